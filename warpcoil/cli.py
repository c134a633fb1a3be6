"""Command line: ``warpcoil validate``, ``warpcoil run SCENE.toml``."""

from __future__ import annotations

import argparse
import sys


def _validate(args: argparse.Namespace) -> int:
    from . import validation

    unknown = sorted(set(args.cases) - set(validation.CASES))
    if unknown:
        print(f"warpcoil validate: unknown case(s) {', '.join(unknown)}; choose from {', '.join(validation.CASES)}",
              file=sys.stderr)
        return 2
    rows = validation.run(args.cases or None)
    print(validation.format_table(rows))
    failed = [r for r in rows if not r.passed]
    print(f"\n{len(rows) - len(failed)} passed, {len(failed)} failed")
    return 1 if failed else 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="warpcoil", description=__doc__)
    sub = parser.add_subparsers(dest="command", required=True)
    from .validation import CASES

    validate = sub.add_parser("validate", help="run the validation cases and print a table; exit 1 on a failure")
    validate.add_argument("cases", nargs="*", metavar="CASE",
                          help=f"subset of: {', '.join(CASES)} (default: all)")
    validate.set_defaults(func=_validate)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    return args.func(args)


if __name__ == "__main__":
    sys.exit(main())
