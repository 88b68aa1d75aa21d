"""Which floating-point results this machine's numerical libraries give (for the bit-for-bit references).

torch's CPU kernels (MKL, oneDNN, ATen's vectorised code) and numpy's SIMD loops pick code paths by the CPU
they run on, so a network's outputs can differ in the last bits between machines (measured: the MAPPO
references recorded on one machine differ from the first update on an AMD EPYC with AVX-512, although every
env digest matches). The references that depend on them (``tests/data/mappo_reference.json``,
``tests/data/learned_replays.json``) are kept per :func:`fingerprint`: a hash of a few computations of the kinds
the trainers do. On a machine none of them was recorded on, the tests compare with the first recording.
"""

from __future__ import annotations

import hashlib

import numpy as np


def fingerprint() -> str:
    """16 hex digits: the bits of a small MLP's forward and backward pass in torch (float32, one thread, the
    trainers' settings) and of numpy's transcendental and BLAS routines on fixed inputs."""
    import torch

    h = hashlib.sha256()
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        g = torch.Generator().manual_seed(0)
        x = torch.randn(64, 37, generator=g)
        net = torch.nn.Sequential(torch.nn.Linear(37, 64), torch.nn.Tanh(), torch.nn.Linear(64, 64), torch.nn.Tanh(),
                                  torch.nn.Linear(64, 2))
        with torch.no_grad():
            for p in net.parameters():
                p.copy_(torch.randn(p.shape, generator=g) * 0.3)
        y = net(x)
        dist = torch.distributions.Normal(y, torch.full_like(y, 0.4).exp())
        logp = dist.log_prob(torch.zeros_like(y)).sum()
        logp.backward()
        for t in (y.detach(), logp.detach(), *(p.grad for p in net.parameters() if p.grad is not None)):
            h.update(t.numpy().tobytes())
    finally:
        torch.set_num_threads(threads)
    rng = np.random.default_rng(0)
    a = rng.normal(size=(64, 64))
    for v in (np.exp(a), np.log1p(np.abs(a)), np.tanh(a), np.sin(a), np.arctan2(a, a.T), a @ a.T):
        h.update(np.ascontiguousarray(v).tobytes())
    return h.hexdigest()[:16]
