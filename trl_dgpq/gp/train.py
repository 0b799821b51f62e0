"""Fit kernel hyperparameters (and a manifold kernel's MLP) jointly with the noise by
minimising each GP's exact negative log marginal likelihood
(``ExactGP.neg_log_marginal_likelihood``) with autograd and Adam, then re-factorise
the GPs with the new kernel (``ExactGP.refit``). Only the GP's public API is used:
its kernel's parameters (one set per GP for a kernel with ``batch_shape (N,)``, one
shared set for ``()``), its likelihood's ``raw_noise`` and ``commit``, ``size``.

Each GP's loss touches only its own rows of per-GP parameters, so GPs - and seeds -
stay independent. Trouble (a failed factorisation, a non-finite loss or parameter)
freezes that GP at its last good parameters and is logged; nothing NaN is ever left
behind. With a shared kernel the first trouble ends the fit.

Each call starts a fresh Adam, so no optimiser state outlives it: a GP's trained
state is its kernel parameters and noise, which its ``state_dict`` holds.
"""
from __future__ import annotations

import logging
from typing import List, Optional, Tuple

import torch

from .base import GPNumericalError
from .exact import ExactGP

log = logging.getLogger(__name__)


class _LastGood:
    """The last good values of the trained tensors, for the GPs ``rows`` (flat indices):
    a per-GP tensor (GP rows first) is saved and restored by rows, a shared one whole."""

    def __init__(self, tensors: List[Tuple[torch.Tensor, bool]], rows: torch.Tensor):
        self.items = [(t, per_gp, t.detach().clone()) for t, per_gp in tensors]
        self.rows = rows

    def save(self, which: torch.Tensor) -> None:
        """Remember the current values of the GPs ``which`` (a mask over rows)."""
        self._copy(which, to_good=True)

    def restore(self, which: torch.Tensor) -> None:
        """Put the GPs ``which`` back to their last good values (a shared tensor: all)."""
        if which.any():
            self._copy(which, to_good=False)

    @torch.no_grad()
    def _copy(self, which: torch.Tensor, to_good: bool) -> None:
        r = self.rows[which]
        for t, per_gp, good in self.items:
            dst, src = (good, t) if to_good else (t, good)
            if per_gp:
                dst[r] = src[r]
            else:
                dst.copy_(src)


def fit(gp: ExactGP, mask: Optional[torch.Tensor] = None, steps: int = 100, lr: float = 0.01,
        min_points: int = 2, train_noise: bool = True) -> dict:
    """Train the kernel parameters and noise of the selected GPs (``mask`` over the
    batch, None: all) holding at least ``min_points`` points, on the data they hold.

    Returns ``{"rows", "nll_before", "nll_after", "frozen"}`` (flat indices of the
    trained GPs, and per trained GP the NLL of its data before and after, and whether
    trouble froze it). With a shared kernel (e.g. ``RBFKernel()``), the summed NLL of
    the selected GPs is minimised and every GP holding data is re-factorised.
    """
    if not isinstance(gp, ExactGP):
        raise TypeError("fitting needs the GP's data: use ExactGP (the sparse GP keeps only basis vectors)")
    chosen = gp.size >= min_points
    if mask is not None:
        chosen &= torch.as_tensor(mask, device=gp.device).reshape(gp.batch_shape).to(torch.bool)
    rows = chosen.reshape(-1).nonzero().squeeze(-1)
    frozen = torch.zeros(rows.numel(), dtype=torch.bool, device=gp.device)
    if rows.numel() == 0:
        none = torch.zeros(0, dtype=gp.dtype, device=gp.device)
        return dict(rows=rows, nll_before=none, nll_after=none.clone(), frozen=frozen)
    shared = not gp.kernel.batch_shape
    params = [p for p in gp.kernel.parameters() if p.requires_grad]
    noise = gp.likelihood.raw_noise
    good = _LastGood([(p, not shared) for p in params] + [(noise, True)], rows)
    opt = torch.optim.Adam(params + ([noise] if train_noise else []), lr=lr)
    with torch.enable_grad():
        nll_before = gp.neg_log_marginal_likelihood(chosen)[0].detach()
        for _ in range(steps):
            nll, ok = gp.neg_log_marginal_likelihood(chosen)
            newly_bad = ~(ok & torch.isfinite(nll)) & ~frozen
            if newly_bad.any():
                good.restore(newly_bad)
                frozen |= newly_bad
                log.warning("kernel fit: %d GP(s) hit a failed factorisation or non-finite NLL; "
                            "kept their last good parameters", int(newly_bad.sum()))
            if frozen.all() or (shared and frozen.any()):
                break
            good.save(~frozen)  # this step's parameters are good: remember them
            opt.zero_grad()
            nll[~frozen].sum().backward()  # frozen GPs' rows get zero gradients
            opt.step()
            good.restore(frozen)  # Adam's momentum would keep moving frozen GPs: undo
    with torch.no_grad():
        nll_after, ok = gp.neg_log_marginal_likelihood(chosen)
        bad = ~(ok & torch.isfinite(nll_after)) | ~torch.isfinite(noise[rows])
        if bad.any():
            good.restore(bad)
            frozen |= bad
            log.warning("kernel fit: %d GP(s) ended in trouble; kept their last good parameters", int(bad.sum()))
            nll_after, _ = gp.neg_log_marginal_likelihood(chosen)
    gp.likelihood.commit(rows)
    # A shared kernel changed for every GP holding data, not only the trained ones.
    changed = gp.size > 0 if shared else chosen
    try:
        gp.refit(changed)
    except GPNumericalError as err:  # cannot happen after the checks above, but never leave a broken GP
        good.restore(torch.ones_like(frozen))
        gp.likelihood.commit(rows)
        log.warning("kernel fit: re-factorisation failed (%s); restored the previous parameters", err)
        gp.refit(changed)
    return dict(rows=rows, nll_before=nll_before, nll_after=nll_after, frozen=frozen)
