"""The online-thesis adaptive loop written plainly in PyTorch (eager, CPU, float32), for ``jax_vs_torch``.

This is a second implementation of the adaptive self-calibration loop of
:mod:`jaxcal.online_thesis` (thesis sections 4.4-4.5), written the way a PyTorch user would: two
``torch.nn`` 3-5-10-5-3 leaky-ReLU(0.1) networks, ``torch.optim.Adam`` (optax's ``adam`` defaults:
betas 0.9/0.999, eps 1e-8; one optimiser per network whose moments persist from one sequence to the
next, as in jaxcal), and a Python ``for`` over the training sequences. Per sequence:

1. gyroscope update (eq. 4.9-4.10): ``a_c = NN_a(a)`` without gradient; ``gyr_steps`` Adam steps on
   ``mean |a_c,n+1 - Exp(phi_c,n dt)^T a_c,n|^2 / 3`` with ``phi_c = NN_phi(phi)``;
2. accelerometer update (eq. 4.11-4.13): ``phi_c`` from the updated ``NN_phi`` and
   ``a_phi,N = R_tot^T a_c,1`` without gradient (``R_tot = R_1 ... R_{N-1}``); ``acc_steps`` Adam
   steps on ``w |a_phi,N - a_c,N|^2 / 3 + (1 - w) |1 - |a_c,N||``;
3. the loss of each network after its update, as jaxcal's result records (``gyr_loss``, ``acc_loss``).

Only the adaptive loop is here (jaxcal with ``init_epochs = 0``): the networks start from given
weights (copied from jaxcal's flax parameters by :func:`mlp_from_flax`). The same arithmetic as
jaxcal -- eq. 3.7 normalisation, the small-angle branch of ``Exp`` with its double ``where`` (the
stationary samples have zero rate), the physical rotation convention -- in float32. Work that does
not depend on the trained weights within a sequence is computed once per sequence (``a_c``,
``a_c,1 = a_c[0]``, ``R_tot``), as a PyTorch user would; jaxcal recomputes ``a_c,1`` and ``R_tot``
inside its loss function. ``R_tot`` is either the left-to-right product (``compose="loop"``, jaxcal's
order) or a pairwise tree of batched products (``compose="tree"``, 7 ``bmm`` instead of 100 ``@``).

Dimension letters: ``M`` sequences, ``N`` samples per sequence.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Literal, NamedTuple

import numpy as np
import torch
from jaxtyping import Float
from torch import Tensor, nn

__all__ = [
    "TorchLoopConfig",
    "TorchLoopResult",
    "acc_loss",
    "adaptive_loop",
    "compose",
    "exp_so3",
    "flax_from_mlp",
    "gyro_loss",
    "mlp_from_flax",
    "normalise",
]

Compose = Literal["loop", "tree"]

# Below this squared angle the Taylor series replaces the closed form (jaxcal.rotation._SMALL_ANGLE_SQ).
SMALL_ANGLE_SQ = 1e-6


class TorchLoopConfig(NamedTuple):
    """Hyperparameters of the adaptive loop (plain Python numbers; all static for PyTorch).

    Attributes:
        gyr_lr: Adam step size of the gyroscope updates.
        gyr_steps: Adam steps per sequence for ``NN_phi``.
        acc_lr: Adam step size of the accelerometer updates.
        acc_steps: Adam steps per sequence for ``NN_a``.
        w: weight of the rotation term in eq. 4.13.
        dt: sample period (s).
        compose: how ``R_tot`` is multiplied out (``"loop"``: left to right; ``"tree"``: pairwise).
        adam_impl: ``torch.optim.Adam`` implementation: ``"default"``, ``"foreach"`` or ``"fused"``.
    """

    gyr_lr: float = 1e-4
    gyr_steps: int = 1
    acc_lr: float = 3e-5
    acc_steps: int = 1
    w: float = 0.9
    dt: float = 0.01
    compose: Compose = "tree"
    adam_impl: Literal["default", "foreach", "fused"] = "fused"


class TorchLoopResult(NamedTuple):
    """Outcome of :func:`adaptive_loop`; the networks themselves are trained in place.

    Attributes:
        gyr_loss, acc_loss: ``(M,)`` eq. 4.10 / eq. 4.13 loss of each sequence after its update.
    """

    gyr_loss: Float[Tensor, " M"]
    acc_loss: Float[Tensor, " M"]


# ----------------------------------------------------------------------------- networks


def mlp_from_flax(params: Mapping, slope: float = 0.1) -> nn.Sequential:
    """A ``torch.nn`` MLP with the weights of a flax ``Dense_0 ... Dense_K`` parameter dict.

    flax's ``Dense`` computes ``x @ kernel + bias`` with ``kernel`` of shape ``(in, out)``;
    ``nn.Linear`` computes ``x @ weight.T + bias``, so ``weight = kernel.T``.

    Args:
        params: flax parameters (``{"Dense_i": {"kernel", "bias"}}``, arrays of any kind).
        slope: leaky-ReLU negative slope of the hidden layers.
    """
    names = sorted(params, key=lambda k: int(k.split("_")[1]))
    layers: list[nn.Module] = []
    for i, name in enumerate(names):
        kernel = np.asarray(params[name]["kernel"], np.float32)
        lin = nn.Linear(kernel.shape[0], kernel.shape[1])
        with torch.no_grad():
            lin.weight.copy_(torch.from_numpy(kernel.T.copy()))
            lin.bias.copy_(torch.from_numpy(np.asarray(params[name]["bias"], np.float32).copy()))
        layers.append(lin)
        if i < len(names) - 1:
            layers.append(nn.LeakyReLU(slope))
    return nn.Sequential(*layers)


def flax_from_mlp(net: nn.Sequential) -> dict:
    """The weights of ``net`` as a flax-layout dict of numpy arrays (inverse of :func:`mlp_from_flax`)."""
    lins = [m for m in net if isinstance(m, nn.Linear)]
    return {f"Dense_{i}": {"kernel": lin.weight.detach().numpy().T.copy(), "bias": lin.bias.detach().numpy().copy()}
            for i, lin in enumerate(lins)}


def normalise(y: Float[Tensor, "... 3"], lo: Float[Tensor, "3"], hi: Float[Tensor, "3"]) -> Float[Tensor, "... 3"]:
    """Eq. 3.7: ``2 (y - lo) / (hi - lo) - 1``.

    Args:
        y: raw counts (LSB).
        lo, hi: eq. 3.6 bounds (LSB).
    """
    return 2.0 * (y - lo) / (hi - lo) - 1.0


# ----------------------------------------------------------------------------- rotations and losses


def exp_so3(v: Float[Tensor, "... 3"]) -> Float[Tensor, "... 3 3"]:
    """``I + sin(t)/t [v]x + (1 - cos t)/t^2 [v]x^2``, ``t = |v|``, as :func:`jaxcal.rotation.exp_so3`
    (Taylor series below ``t^2 = 1e-6``, double ``where`` so the unused branch gives no NaN gradient)."""
    theta_sq = (v * v).sum(-1)
    small = theta_sq < SMALL_ANGLE_SQ
    t = torch.sqrt(torch.where(small, torch.ones_like(theta_sq), theta_sq))
    half = 0.5 * t
    a = torch.where(small, 1.0 - theta_sq / 6.0 + theta_sq**2 / 120.0, torch.sin(t) / t)
    b = torch.where(small, 0.5 - theta_sq / 24.0 + theta_sq**2 / 720.0, 0.5 * (torch.sin(half) / half) ** 2)
    x, y, z = v.unbind(-1)
    o = torch.zeros_like(x)
    k = torch.stack([torch.stack([o, -z, y], -1), torch.stack([z, o, -x], -1), torch.stack([-y, x, o], -1)], -2)
    eye = torch.eye(3, dtype=v.dtype)
    return eye + a[..., None, None] * k + b[..., None, None] * (k @ k)


def compose(rs: Float[Tensor, "N 3 3"], how: Compose = "tree") -> Float[Tensor, "3 3"]:
    """Ordered product ``R_1 R_2 ... R_N``.

    Args:
        rs: rotations in time order.
        how: ``"loop"`` (left to right, jaxcal's order) or ``"tree"`` (pairwise: neighbours are
            multiplied in one batched product per level; same product, other rounding).
    """
    if how == "loop":
        out = torch.eye(3, dtype=rs.dtype)
        for r in rs:
            out = out @ r
        return out
    while rs.shape[0] > 1:
        if rs.shape[0] % 2:  # odd: the last one waits for the next level
            rs = torch.cat([torch.bmm(rs[:-1:2], rs[1::2]), rs[-1:]])
        else:
            rs = torch.bmm(rs[0::2], rs[1::2])
    return rs[0]


def gyro_loss(phi_c: Float[Tensor, "N 3"], a_c: Float[Tensor, "N 3"], dt: float) -> Float[Tensor, ""]:
    """Eq. 4.9-4.10 (physical convention): ``mean_n |a_c,n+1 - Exp(phi_c,n dt)^T a_c,n|^2 / 3``.

    Args:
        phi_c: calibrated rates (rad/s).
        a_c: calibrated specific force (g).
        dt: sample period (s).
    """
    r = exp_so3(phi_c[:-1] * dt)
    a_phi = torch.einsum("nji,nj->ni", r, a_c[:-1])
    return ((a_c[1:] - a_phi) ** 2).mean()


def acc_loss(a_phi: Float[Tensor, "3"], a_cN: Float[Tensor, "3"], w: float) -> Float[Tensor, ""]:
    """Eq. 4.13: ``w |a_phi,N - a_c,N|^2 / 3 + (1 - w) |1 - |a_c,N||`` (``a_phi,N = R_tot^T a_c,1``, fixed).

    Args:
        a_phi: the fixed target ``R_tot^T a_c,1`` (g).
        a_cN: calibrated specific force at the last sample (g).
        w: weight of the rotation term.
    """
    l1 = ((a_phi - a_cN) ** 2).mean()
    l2 = torch.abs(1.0 - torch.sqrt((a_cN**2).sum()))
    return w * l1 + (1.0 - w) * l2


# ----------------------------------------------------------------------------- the loop


def _adam(net: nn.Module, lr: float, impl: str) -> torch.optim.Adam:
    kw = {"foreach": True} if impl == "foreach" else {"fused": True} if impl == "fused" else {"foreach": False}
    return torch.optim.Adam(net.parameters(), lr=lr, betas=(0.9, 0.999), eps=1e-8, **kw)


def adaptive_loop(
    acc: Float[Tensor, "M N 3"],
    gyr: Float[Tensor, "M N 3"],
    acc_bounds: tuple[Tensor, Tensor],
    gyr_bounds: tuple[Tensor, Tensor],
    net_a: nn.Module,
    net_g: nn.Module,
    cfg: TorchLoopConfig,
) -> TorchLoopResult:
    """The adaptive loop over the ``M`` sequences in order; trains ``net_a`` and ``net_g`` in place.

    Args:
        acc, gyr: raw accelerometer / gyroscope counts of the training sequences (LSB, float32).
        acc_bounds, gyr_bounds: ``(lo, hi)`` eq. 3.6 bounds of each sensor (LSB).
        net_a, net_g: ``NN_a`` and ``NN_phi`` (their weights are the starting point; updated in place).
        cfg: hyperparameters.
    """
    opt_a, opt_g = _adam(net_a, cfg.acc_lr, cfg.adam_impl), _adam(net_g, cfg.gyr_lr, cfg.adam_impl)
    u_acc, u_gyr = normalise(acc, *acc_bounds), normalise(gyr, *gyr_bounds)
    m = acc.shape[0]
    l_g, l_a = torch.empty(m), torch.empty(m)
    dt, w = cfg.dt, cfg.w
    for i in range(m):
        u_a, u_g = u_acc[i], u_gyr[i]
        # (a) gyroscope update, NN_a fixed.
        with torch.no_grad():
            a_c = net_a(u_a)
        for _ in range(cfg.gyr_steps):
            opt_g.zero_grad(set_to_none=True)
            gyro_loss(net_g(u_g), a_c, dt).backward()
            opt_g.step()
        # (b) accelerometer update, NN_phi fixed, a_phi,N a fixed target.
        with torch.no_grad():
            phi_c = net_g(u_g)
            l_g[i] = gyro_loss(phi_c, a_c, dt)
            a_phi = compose(exp_so3(phi_c[:-1] * dt), cfg.compose).T @ a_c[0]
        u_last = u_a[-1]
        for _ in range(cfg.acc_steps):
            opt_a.zero_grad(set_to_none=True)
            acc_loss(a_phi, net_a(u_last), w).backward()
            opt_a.step()
        with torch.no_grad():
            l_a[i] = acc_loss(a_phi, net_a(u_last), w)
    return TorchLoopResult(gyr_loss=l_g, acc_loss=l_a)
