"""Warp kernels, grouped by pass: rod geometry, elastic forces, integration, contact."""
