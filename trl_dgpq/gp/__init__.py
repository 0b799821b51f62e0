"""Batched Gaussian processes in torch (float64 by default).

    from trl_dgpq.gp import RBFKernel, ExactGP, SparseOnlineGP
    k  = RBFKernel(lengthscale=0.05, outputscale=1.0)
    gp = ExactGP(k, noise_var=0.1, dim=2, batch_shape=(S, A), capacity=1024)
    sp = SparseOnlineGP(k, noise_var=0.1, dim=2, batch_shape=(S, A), budget=100, novelty_tol=1e-3)
    gp.add(x, y, mask=None)     # x (*batch, dim), y (*batch,), mask (*batch,) bool
    mean, var = gp.predict(xq)  # xq (*batch, q, dim) -> (*batch, q) each; var is latent (no noise)
    gp.reset(mask=None)
    gp.size                     # (*batch,) stored points / basis vectors
"""
from .base import BatchedGP, GPNumericalError
from .exact import ExactGP
from .kernels import RBFKernel
from .manifold import ManifoldKernel
from .sparse import SparseOnlineGP
from .train import fit
from .factory import GP_BACKENDS, KERNELS, GPConfig, make_gp, make_kernel

__all__ = ["BatchedGP", "GPNumericalError", "ExactGP", "SparseOnlineGP", "RBFKernel", "ManifoldKernel", "fit",
           "GPConfig", "GP_BACKENDS", "KERNELS", "make_gp", "make_kernel"]
