"""The interface every GP backend implements, and the batching around it.

A backend object (a model, in GPyTorch's words) holds ``prod(batch_shape)``
independent zero-mean GPs. It owns a kernel (``gp.kernel``, see ``kernels``) and a
``GaussianLikelihood`` (``gp.likelihood``, the per-GP observation noise). Its
state lives in tensors with one flat leading dimension ``N``, and so do the
kernel's parameters when it has one set per GP (kernel ``batch_shape (N,)``; a
kernel with ``batch_shape ()`` is shared by all N). Public methods take and
return tensors with the caller's ``batch_shape`` in front; a ``mask`` over the
batch selects which GPs take part. Selected GPs are *gathered* into a compact
sub-batch, updated, and written back, so touching one GP of each seed costs one
GP's work, not ``A`` of them (DGPQ touches only the taken action's GP). A
sub-batch evaluates ``kernel.select(rows)``, the kernel of just those GPs.

Backends implement:
    _state_names          names of the state tensors (leading dim N)
    _empty_state(k)       dict of state tensors for k empty GPs
    _add(st, x, y, gate)  update state dict ``st`` in place with one point per GP
    _predict(st, xq)      mean, latent variance (k, q)
using ``_kernel(st)`` and ``_noise(st)``, the kernel and noise of the GPs of ``st``.
"""
from __future__ import annotations

import math
from typing import Dict, Optional, Sequence, Tuple

import numpy as np
import torch
from torch import nn

from .kernels import DTYPE, Kernel
from .likelihood import GaussianLikelihood

State = Dict[str, torch.Tensor]


class GPNumericalError(RuntimeError):
    """A factorisation failed even after the jitter ladder."""


def check_finite(t: torch.Tensor, name: str) -> None:
    if not torch.isfinite(t).all():
        raise ValueError(f"{name} contains NaN or inf")


class BatchedGP(nn.Module):
    """Base class: a batch of independent zero-mean GPs (see module docstring)."""

    _state_names: Tuple[str, ...] = ()

    def __init__(self, kernel: Kernel, noise_var: float, dim: int,
                 batch_shape: Sequence[int] = (), dtype=DTYPE, device=None):
        """kernel: batch_shape () (shared) or (prod(batch_shape),) (one set per GP);
        noise_var: the initial observation noise of every GP (see ``likelihood``)."""
        super().__init__()
        if int(dim) != dim or dim < 1:
            raise ValueError(f"dim must be a positive integer, got {dim}")
        batch_shape = torch.Size(batch_shape)
        if any(b < 1 for b in batch_shape):
            raise ValueError(f"batch_shape entries must be >= 1, got {tuple(batch_shape)}")
        if not isinstance(kernel, Kernel):
            raise TypeError(f"kernel must be a trl_dgpq.gp.Kernel, got {type(kernel).__name__}")
        self.num_gps = math.prod(batch_shape)
        if kernel.batch_shape not in (torch.Size(), torch.Size([self.num_gps])):
            raise ValueError(f"kernel batch_shape {tuple(kernel.batch_shape)} must be () (shared) or "
                             f"({self.num_gps},) (one set per GP) for batch_shape {tuple(batch_shape)}")
        self.device = torch.device(device) if device is not None else torch.device("cpu")
        self.kernel = kernel.to(dtype=dtype, device=device)
        # Per-GP observation noise (trainable by trl_dgpq.gp.train); survives reset().
        self.likelihood = GaussianLikelihood(noise_var, (self.num_gps,), dtype=dtype, device=self.device)
        self.dim = int(dim)
        self.batch_shape = batch_shape
        self.dtype = dtype
        for name, t in self._empty_state(self.num_gps).items():
            self.register_buffer(name, t)

    # ------------------------------------------------------------------ public
    @property
    def size(self) -> torch.Tensor:
        """Number of stored points (exact) or basis vectors (sparse), ``batch_shape``."""
        return self.n.view(self.batch_shape)

    @torch.no_grad()
    def add(self, x: torch.Tensor, y: torch.Tensor, mask: Optional[torch.Tensor] = None) -> None:
        """Condition the selected GPs on one observation each.

        x: ``(*batch, dim)``; y: ``(*batch,)``; mask: ``(*batch,)`` bool or None (all).
        """
        self._update(x, y, mask, None)

    @torch.no_grad()
    def add_if_uncertain(self, x: torch.Tensor, y: torch.Tensor, var_tol: float,
                         mask: Optional[torch.Tensor] = None):
        """Add (x, y) only to the selected GPs whose latent variance at x exceeds
        ``var_tol``; report the variance before and the posterior after, at x.

        The gated update of DGPQ (steps 4-5), in one pass: the backends get the
        posterior at x from the rank-one update itself, not from fresh predictions.
        x ``(*batch, dim)``, y ``(*batch,)``. Returns ``var_before, mean_after,
        var_after, added``, each ``(*batch,)``; unselected GPs report their prior
        and ``added=False``.
        """
        return self._update(x, y, mask, float(var_tol))

    def _update(self, x, y, mask, gate):
        x = self._check(x, "x", (*self.batch_shape, self.dim)).reshape(self.num_gps, self.dim)
        y = self._check(y, "y", tuple(self.batch_shape)).reshape(self.num_gps)
        rows = self._rows(mask)
        self._rows_in_flight = rows
        if rows is None:
            self._prepare_add(None)
            out = self._add(self._state(), x, y, gate)
        elif rows.numel():
            self._prepare_add(rows)
            width = self._width(self.n[rows], adding=True)
            st = self._state(rows, width)
            out = self._add(st, x[rows], y[rows], gate)
            if gate is None or out[3].any():
                self._write(rows, st, width)
        if gate is None:
            return None
        if rows is not None:  # unselected GPs report their prior
            prior = self.kernel.diag(x)
            res = (prior.clone(), torch.zeros_like(prior), prior.clone(),
                   torch.zeros(self.num_gps, dtype=torch.bool, device=self.device))
            if rows.numel():
                for full, part in zip(res, out):
                    full[rows] = part
            out = res
        var1, mean2, var2, added = (t.view(self.batch_shape) for t in out)
        return var1.clamp_min(0), mean2, var2.clamp_min(0), added

    @torch.no_grad()
    def predict(self, xq: torch.Tensor, mask: Optional[torch.Tensor] = None):
        """Posterior mean and latent variance (no noise) at ``xq``.

        xq: ``(*batch, q, dim)`` -> mean, var each ``(*batch, q)``. GPs outside
        ``mask`` are not evaluated and report their prior (mean 0, var k(x, x)).
        Variances are clamped at 0 against round-off.
        """
        if xq.dim() != len(self.batch_shape) + 2:
            raise ValueError(f"xq must have shape (*batch_shape, q, dim) = "
                             f"({', '.join(map(str, self.batch_shape))}, q, {self.dim}); got {tuple(xq.shape)}")
        q = xq.shape[-2]
        xq = self._check(xq, "xq", (*self.batch_shape, q, self.dim)).reshape(self.num_gps, q, self.dim)
        rows = self._rows(mask)
        if rows is None:
            mean, var = self._predict(self._state(), xq)
        else:
            mean = xq.new_zeros(self.num_gps, q)
            var = self.kernel.diag(xq).clone()
            if rows.numel():
                m, v = self._predict(self._state(rows, self._width(self.n[rows])), xq[rows])
                mean[rows], var[rows] = m, v
        shape = (*self.batch_shape, q)
        return mean.view(shape), var.clamp_min(0).view(shape)

    @torch.no_grad()
    def reset(self, mask: Optional[torch.Tensor] = None) -> None:
        """Empty the selected GPs (all when mask is None)."""
        rows = self._rows(mask)
        if rows is None:
            rows = torch.arange(self.num_gps, device=self.device)
        if rows.numel():
            self._clear(rows)

    # --------------------------------------------------------------- helpers
    def _check(self, t: torch.Tensor, name: str, shape) -> torch.Tensor:
        if not torch.is_tensor(t):
            t = torch.as_tensor(t)
        if tuple(t.shape) != tuple(shape):
            raise ValueError(f"{name} must have shape {tuple(shape)}, got {tuple(t.shape)}")
        t = t.to(dtype=self.dtype, device=self.device)
        check_finite(t, name)
        return t

    def _rows(self, mask: Optional[torch.Tensor]) -> Optional[torch.Tensor]:
        """Flat indices of the selected GPs, or None for 'all of them'."""
        if mask is None:
            return None
        mask = torch.as_tensor(mask, device=self.device)
        if mask.dtype != torch.bool or tuple(mask.shape) != tuple(self.batch_shape):
            raise ValueError(f"mask must be a bool tensor of shape {tuple(self.batch_shape)}, "
                             f"got {mask.dtype} {tuple(mask.shape)}")
        mask = mask.reshape(-1)
        rows = mask.nonzero().squeeze(-1)
        return None if rows.numel() == self.num_gps else rows

    def _state(self, rows: Optional[torch.Tensor] = None, width: Optional[int] = None) -> State:
        """The state of all GPs (views), or a copy of the selected rows; with ``width``,
        only the first ``width`` slots along dim 1 (see ``_width``)."""
        if rows is None:
            st = {k: getattr(self, k) for k in self._state_names}
        elif width is None:
            st = {k: getattr(self, k).index_select(0, rows) for k in self._state_names}
        else:
            # index_select on the narrowed view copies only what is used (t[rows, :w] copies whole rows first)
            st = {k: getattr(self, k)[rows] if k == "n" else self._narrow(k, getattr(self, k), width).index_select(0, rows)
                  for k in self._state_names}
        st["rows"] = rows  # which GPs, for the kernel and noise (None = all)
        return st

    def _kernel(self, st: State):
        """The kernel of the GPs of ``st``, called on inputs with their leading dim k."""
        return self.kernel.select(st["rows"])

    def _noise(self, st: State) -> torch.Tensor:
        """Observation noise of the GPs of ``st``, (k,)."""
        noise = self.likelihood.noise
        return noise if st["rows"] is None else noise[st["rows"]]

    def _write(self, rows: torch.Tensor, st: State, width: Optional[int] = None) -> None:
        for k in self._state_names:
            if width is None or k == "n":
                getattr(self, k).index_copy_(0, rows, st[k])
            else:
                self._narrow(k, getattr(self, k), width)[rows] = st[k]

    def _save_to_state_dict(self, destination, prefix, keep_vars):
        """A saved GP holds its used slots only (``_width``; a checkpoint of 42 sparse GPs that
        use 10 of 101 slots: 0.3 MB, not 6.9): the zeros beyond them come back on load."""
        super()._save_to_state_dict(destination, prefix, keep_vars)
        width = self._width(self.n)
        if width is not None:
            for k in self._state_names:
                if k != "n":  # a copy: a saved view would carry its whole storage
                    destination[prefix + k] = self._narrow(k, destination[prefix + k], width).clone()

    def _load_from_state_dict(self, state_dict, prefix, *args, **kwargs):
        for k in self._state_names:
            saved, full = state_dict.get(prefix + k), getattr(self, k)
            if k == "n" or saved is None or saved.shape == full.shape or saved.dim() != full.dim():
                continue
            padded = torch.zeros_like(full)
            region = self._narrow(k, padded, saved.shape[1])
            if region.shape == saved.shape:  # else: nn.Module's own size-mismatch error names it
                region.copy_(saved)
                state_dict[prefix + k] = padded
        super()._load_from_state_dict(state_dict, prefix, *args, **kwargs)

    def _width(self, n: torch.Tensor, adding: bool = False) -> Optional[int]:
        """How many leading slots (dim 1 of every state tensor but n) GPs with counts
        ``n`` use, so that a gather copies only those; None = all. Backends whose
        slots beyond the count are all zero may override this."""
        return None

    def _narrow(self, name: str, t: torch.Tensor, width: int) -> torch.Tensor:
        """The view of state tensor ``name`` that covers ``width`` slots."""
        return t[:, :width]

    def _clear(self, rows: torch.Tensor) -> None:
        """Empty the GPs ``rows``."""
        self._write(rows, self._empty_state(rows.numel()))

    def _prepare_add(self, rows: Optional[torch.Tensor]) -> None:
        """Hook run before an add, e.g. to grow storage."""

    def _global_rows(self, local: torch.Tensor) -> torch.Tensor:
        """Map indices into the sub-batch being updated to flat GP indices."""
        rows = getattr(self, "_rows_in_flight", None)
        return local if rows is None else rows[local]

    def _gp_names(self, flat_rows: torch.Tensor) -> str:
        """Human-readable batch indices for error messages."""
        idx = [tuple(int(i) for i in np.unravel_index(r, self.batch_shape)) if self.batch_shape else ()
               for r in flat_rows.reshape(-1)[:5].tolist()]
        more = "" if flat_rows.numel() <= 5 else f" (+{flat_rows.numel() - 5} more)"
        return f"{type(self).__name__} batch index {', '.join(map(str, idx))}{more}"

    # ------------------------------------------------------- backend contract
    def _empty_state(self, k: int) -> State:
        raise NotImplementedError

    def _add(self, st: State, x: torch.Tensor, y: torch.Tensor, gate: Optional[float]):
        """Add (x_i, y_i) to GP i of ``st`` in place, only where its variance at x_i
        exceeds ``gate`` (all when None). Returns ``(var_before, mean_after,
        var_after, added)`` at x, each (k,)."""
        raise NotImplementedError

    def _predict(self, st: State, xq: torch.Tensor):
        raise NotImplementedError
