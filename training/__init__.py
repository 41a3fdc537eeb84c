"""PyTorch reference implementation of Temporal Cascaded Diffusion (TCD).

This package is the ground truth the Rust engine is validated against and the tool that trains,
evaluates and exports the models shipped with ``tcd-forecast``. It is not part of the wheel.
"""
