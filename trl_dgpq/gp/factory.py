"""The GP part of an agent's configuration, and the factory that builds it. (When and
how an agent trains its kernel is the agent's own setting, e.g. DGPQConfig's.)"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Sequence, Tuple

from ..config import setting
from ..rng import KERNEL_STREAM, SeedStreams
from .exact import ExactGP
from .kernels import RBFKernel
from .manifold import ManifoldKernel
from .sparse import SparseOnlineGP

GP_BACKENDS = {"exact": ExactGP, "sparse": SparseOnlineGP}
KERNELS = ("rbf", "manifold")


@dataclass
class GPConfig:
    """GP model: backend, kernel, noise."""
    backend: str = setting("sparse", "GP backend: sparse (Csato-Opper, bounded budget) or exact",
                           choices=tuple(GP_BACKENDS), flag="gp")
    noise_var: float = setting(0.1, "observation noise omega_n^2", within="(0, inf)")
    lengthscale: float = setting(0.05, "RBF bandwidth theta", within="(0, inf)")
    outputscale: float = setting(1.0, "RBF amplitude s_f^2", within="(0, inf)")
    budget: int = setting(100, "sparse GP: basis-vector budget", within="[1, inf)")
    novelty_tol: float = setting(1e-3, "sparse GP: novelty above which a point extends the basis",
                                 within="[0, inf)")
    capacity: int = setting(64, "exact GP: initial points of storage per GP (doubles when full)",
                            within="[1, inf)")
    kernel: str = setting("rbf", "rbf, or manifold: RBF on MLP features trained by NLL (needs gp exact)",
                          choices=KERNELS)
    kernel_hidden: Tuple[int, ...] = setting((10,), "manifold: hidden widths, e.g. 10 or 16,16",
                                             within="[1, inf)", length=(1, None))
    kernel_skip: bool = setting(True, "manifold: features x + MLP(x), starting as the RBF kernel "
                                      "(--no-kernel-skip: the plain MLP output)")

    def cross_check(self) -> None:
        if self.kernel == "manifold" and self.backend != "exact":
            raise ValueError("kernel 'manifold' trains on the GP's data, which only gp 'exact' keeps: use --gp exact")

    def bytes_per_gp(self, dim: int) -> int:
        """Storage of one GP's state (float64), for refusing runs that cannot fit."""
        if self.backend == "sparse":
            m = self.budget + 1
            return 8 * (m * dim + m + 2 * m * m)
        c = self.capacity
        return 8 * c * (dim + 2 + c)


def make_kernel(cfg: GPConfig, dim: int, seeds: Sequence[int], gps_per_seed: int):
    """The config's kernel: a shared RBF kernel (batch_shape ()), or a manifold kernel with
    one feature map per GP (batch_shape (len(seeds) * gps_per_seed,), seed-major),
    initialised from each seed's own random stream."""
    if cfg.kernel == "rbf":
        return RBFKernel(cfg.lengthscale, cfg.outputscale)
    streams = SeedStreams(seeds, stream=KERNEL_STREAM)
    uniform = lambda n, count: streams.uniform(gps_per_seed * count).reshape(n, count)  # noqa: E731
    return ManifoldKernel(len(seeds) * gps_per_seed, dim, cfg.kernel_hidden, cfg.lengthscale, cfg.outputscale,
                          skip=cfg.kernel_skip, uniform=uniform)


def make_gp(cfg: GPConfig, dim: int, batch_shape, kernel, device=None):
    """The GP backend named by ``cfg.backend`` with ``kernel`` and the config's noise."""
    extra = (dict(budget=cfg.budget, novelty_tol=cfg.novelty_tol) if cfg.backend == "sparse"
             else dict(capacity=cfg.capacity))
    return GP_BACKENDS[cfg.backend](kernel, cfg.noise_var, dim, batch_shape=batch_shape, device=device, **extra)
