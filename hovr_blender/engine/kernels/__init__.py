"""Warp kernels. Module-level @wp.func/@wp.kernel (codegen reads real source files)."""
