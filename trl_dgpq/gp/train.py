"""Fit kernel hyperparameters (and a manifold kernel's MLP) jointly with the noise by
minimising each GP's exact negative log marginal likelihood,

    NLL = 1/2 y^T (K + s^2 I)^-1 y + 1/2 log|K + s^2 I| + n/2 log(2 pi),

through the Cholesky factor with autograd and Adam, then re-factorise the GPs with
the new kernel. Each GP's loss touches only its own parameters (for per-GP
kernels), so GPs - and seeds - stay independent. Trouble (a failed factorisation,
a non-finite loss or parameter) freezes that GP at its last good parameters and
is logged; nothing NaN is ever left behind.

Each call starts a fresh Adam, so no optimiser state outlives it: a GP's trained
state is its kernel parameters and noise, which its ``state_dict`` holds.
"""
from __future__ import annotations

import logging
import math
from typing import Optional

import torch

from .base import GPNumericalError
from .exact import ExactGP, cholesky_ladder

log = logging.getLogger(__name__)


def _nll(gp: ExactGP, rows: torch.Tensor, raw_noise: torch.Tensor, X, Y, valid):
    """Per-GP NLL (k,) and a per-GP 'factorisation ok' flag, for padded data."""
    st = {"rows": rows}
    K = gp._k(st, X, X)
    pair = valid[:, :, None] & valid[:, None, :]
    eye = torch.eye(K.shape[-1], dtype=K.dtype, device=K.device)
    noise = raw_noise.exp()
    # Padded rows/cols become identity, which adds exactly 0 to the NLL.
    K = torch.where(pair, K, 0.0) + eye * torch.where(valid, noise[:, None], 1.0)[:, :, None]
    L, info = cholesky_ladder(K, gp._kdiag(st, X).amax(-1).detach())  # per-GP jitter
    ok = info == 0
    z = torch.linalg.solve_triangular(L, (Y * valid)[..., None], upper=False)[..., 0]
    logdet = torch.where(valid, L.diagonal(dim1=-2, dim2=-1).clamp_min(1e-300).log(), 0.0).sum(-1)
    nll = 0.5 * z.square().sum(-1) + logdet + 0.5 * valid.sum(-1) * math.log(2 * math.pi)
    return nll, ok


def fit(gp: ExactGP, mask: Optional[torch.Tensor] = None, steps: int = 100, lr: float = 0.01,
        min_points: int = 2, train_noise: bool = True) -> dict:
    """Train the kernel parameters and noise of the selected GPs on the data they hold.

    Returns ``{"rows", "nll_before", "nll_after", "frozen"}`` (per trained GP; NLL of
    the GP's data). With a kernel shared by all GPs (e.g. ``RBFKernel``), the summed
    NLL of the selected GPs is minimised.
    """
    if not isinstance(gp, ExactGP):
        raise TypeError("fitting needs the GP's data: use ExactGP (the sparse GP keeps only basis vectors)")
    dev = gp.device
    sel = (torch.ones(gp.num_gps, dtype=torch.bool, device=dev) if mask is None
           else mask.reshape(-1).to(device=dev, dtype=torch.bool))
    sel = sel & (gp.n >= min_points)
    rows = sel.nonzero().squeeze(-1)
    if rows.numel() == 0:
        none = torch.zeros(0, dtype=gp.dtype, device=dev)
        return dict(rows=rows, nll_before=none, nll_after=none.clone(),
                    frozen=torch.zeros(0, dtype=torch.bool, device=dev))
    m = int(gp.n[rows].max())
    X, Y = gp.X[rows, :m].clone(), gp.Y[rows, :m].clone()
    valid = torch.arange(m, device=dev) < gp.n[rows][:, None]
    params = [p for p in gp.kernel.parameters() if p.requires_grad]
    snapshot = [p.detach().clone() for p in params]
    raw_noise = gp.noise[rows].log().clone().requires_grad_(train_noise)
    opt = torch.optim.Adam(params + ([raw_noise] if train_noise else []), lr=lr)
    frozen = torch.zeros(rows.numel(), dtype=torch.bool, device=dev)
    per_gp = gp._per_gp

    def restore(which):
        """Put GPs ``which`` (mask over rows) back to their last good parameters."""
        with torch.no_grad():
            for p, good in zip(params, snapshot):
                if per_gp:
                    p[rows[which]] = good[rows[which]]
                else:
                    p.copy_(good)
            raw_noise[which] = last_noise[which]

    with torch.enable_grad():
        last_noise = raw_noise.detach().clone()
        nll0, ok = _nll(gp, rows, raw_noise, X, Y, valid)
        nll_before = nll0.detach().clone()
        for _ in range(steps):
            nll, ok = _nll(gp, rows, raw_noise, X, Y, valid)
            good = ok & torch.isfinite(nll) & ~frozen
            newly_bad = ~good & ~frozen
            if newly_bad.any():
                restore(newly_bad)
                frozen |= newly_bad
                log.warning("kernel fit: %d GP(s) hit a failed factorisation or non-finite NLL; "
                            "kept their last good parameters", int(newly_bad.sum()))
                if not per_gp:
                    break
            if frozen.all():
                break
            for p, good_p in zip(params, snapshot):  # this step's parameters are good: remember them
                if per_gp:
                    good_p[rows[~frozen]] = p.detach()[rows[~frozen]]
                else:
                    good_p.copy_(p.detach())
            last_noise[~frozen] = raw_noise.detach()[~frozen]
            opt.zero_grad()
            nll[~frozen].sum().backward()
            if per_gp:  # frozen GPs take no step
                for p in params:
                    if p.grad is not None:
                        p.grad[rows[frozen]] = 0
                if raw_noise.grad is not None:
                    raw_noise.grad[frozen] = 0
            opt.step()
            if per_gp and frozen.any():  # Adam's momentum would keep moving frozen GPs: undo
                restore(frozen)
        nll_after, ok = _nll(gp, rows, raw_noise, X, Y, valid)
    bad = ~(ok & torch.isfinite(nll_after)) | ~torch.isfinite(raw_noise.detach())
    if bad.any():
        restore(bad)
        frozen |= bad
        log.warning("kernel fit: %d GP(s) ended in trouble; kept their last good parameters", int(bad.sum()))
    with torch.no_grad():
        gp.noise[rows] = raw_noise.detach().exp()
        nll_after, _ = _nll(gp, rows, raw_noise.detach(), X, Y, valid)
    # A kernel shared by all GPs changed for every GP holding data, not only the trained ones.
    changed = (sel if per_gp else gp.n > 0).view(gp.batch_shape)
    try:
        gp.refit(changed)
    except GPNumericalError as err:  # cannot happen after the checks above, but never leave a broken GP
        with torch.no_grad():
            for p, good in zip(params, snapshot):
                p.copy_(good)
        log.warning("kernel fit: re-factorisation failed (%s); restored the previous parameters", err)
        gp.refit(changed)
    return dict(rows=rows, nll_before=nll_before, nll_after=nll_after.detach(), frozen=frozen)
