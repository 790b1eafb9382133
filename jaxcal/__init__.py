"""jaxcal: IMU calibration in JAX.

Modules (see ARCHITECTURE.md): ``rotation`` (axis-angle, eq. 4.1-4.3), ``sensor`` (diag/affine
models), ``normalise`` (eq. 3.6-3.7), ``metrics`` (eq. 2.7, 3.8, 4.14), ``linear`` (eq. 3.1-3.5 with
optimistix), ``nn`` + ``train`` (flax MLP, Adam with early stopping), ``simulate`` (datasets).
"""

__version__ = "0.1.0"
