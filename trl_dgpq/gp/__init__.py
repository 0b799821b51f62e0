"""Batched Gaussian processes in torch (float64 by default), in GPyTorch's shape:
kernel modules with a batch shape, a likelihood module for the noise, GP models
that own both, and a training loop on the models' public API.

    from trl_dgpq.gp import RBFKernel, ManifoldKernel, ExactGP, SparseOnlineGP, fit
    k  = RBFKernel(lengthscale=0.05, outputscale=1.0)   # batch_shape (): shared by all GPs
    km = ManifoldKernel(S * A, dim)                      # batch_shape (S*A,): one set per GP
    K  = km(x1, x2)             # x1 (S*A, n, dim), x2 (S*A, m, dim) -> (S*A, n, m); k.diag(x)
    K  = km.select(rows)(x1, x2)  # the kernel of GPs ``rows`` only: x1 (len(rows), n, dim)
    gp = ExactGP(k, noise_var=0.1, dim=2, batch_shape=(S, A), capacity=1024)
    sp = SparseOnlineGP(k, noise_var=0.1, dim=2, batch_shape=(S, A), budget=100, novelty_tol=1e-3)
    gp.add(x, y, mask=None)     # x (*batch, dim), y (*batch,), mask (*batch,) bool
    mean, var = gp.predict(xq)  # xq (*batch, q, dim) -> (*batch, q) each; var is latent (no noise)
    gp.reset(mask=None)
    gp.size                     # (*batch,) stored points / basis vectors
    gp.likelihood.noise         # (S*A,) observation noise per GP (a GaussianLikelihood)
    nll, ok = gp.neg_log_marginal_likelihood(mask)   # exact GP: per selected GP, differentiable
    gp.refit(mask)              # exact GP: re-factorise after the kernel or noise changed
    fit(gp, mask, steps=50, lr=0.01)   # train kernel and noise by NLL, then refit
"""
from .base import BatchedGP, GPNumericalError
from .exact import ExactGP
from .kernels import Kernel, KernelRows, RBFKernel
from .likelihood import GaussianLikelihood
from .manifold import ManifoldKernel
from .sparse import SparseOnlineGP
from .train import fit
from .factory import GP_BACKENDS, KERNELS, GPConfig, make_gp, make_kernel

__all__ = ["BatchedGP", "GPNumericalError", "ExactGP", "SparseOnlineGP", "Kernel", "KernelRows", "RBFKernel",
           "ManifoldKernel", "GaussianLikelihood", "fit", "GPConfig", "GP_BACKENDS", "KERNELS", "make_gp",
           "make_kernel"]
