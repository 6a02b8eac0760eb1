"""The paper's autoencoder: MLP encoder and an implicit-field decoder g(z, x).

* Encoder: coarse depth and rigid penetration on the encoder sub-lattice (two channels,
  millimetres) -> latent z (size r). Hidden sizes [512, 256, 128], each Linear, LayerNorm,
  ReLU.
* Decoder: (z, query) -> depth (mm) at one surface point. The query is the point's
  normalised position and two 5 x 5 windows (coarse depth, rigid penetration) around it
  (see src/rom/features.rs, which computes the same features in Rust). Hidden sizes
  [512, 256, 128] (the paper's; `decoder_hidden` makes it narrower, the run-time cost per
  decoded point) with LayerNorm and ReLU; the output is a correction added to the coarse
  depth at the point, so the coarse MPM carries the mechanics and the decoder restores the
  detail. The first layer is split into a z part (computed once per evaluation) and a
  query part; this is the same affine map as a Linear on concat(z, query).
* DecoderJacobian: depth and d(depth)/dz for every query point, by an explicit backward
  pass written with ordinary tensor ops (exportable to ONNX), used by the latent refinement.
"""
from __future__ import annotations

import torch
from torch import nn

HIDDEN = (512, 256, 128)
LN_EPS = 1e-5


class Mlp(nn.Module):
    """Linear -> LayerNorm -> ReLU per hidden layer, then a Linear output."""

    def __init__(self, n_in: int, n_out: int, hidden=HIDDEN):
        super().__init__()
        dims = (n_in,) + tuple(hidden)
        self.linears = nn.ModuleList(nn.Linear(a, b) for a, b in zip(dims[:-1], dims[1:]))
        self.norms = nn.ModuleList(nn.LayerNorm(b, eps=LN_EPS) for b in dims[1:])
        self.out = nn.Linear(dims[-1], n_out)

    def forward(self, x):
        for lin, ln in zip(self.linears, self.norms):
            x = torch.relu(ln(lin(x)))
        return self.out(x)


class Encoder(nn.Module):
    def __init__(self, n_in: int, latent: int):
        super().__init__()
        self.mlp = Mlp(n_in, latent)

    def forward(self, observation):  # [B, n_in] -> [B, r]
        return self.mlp(observation)


class Decoder(nn.Module):
    """g(z, q): depth (mm) at query points. Per-point MLP with the z term shared."""

    def __init__(self, latent: int, n_query: int, coarse_index: int, hidden=HIDDEN):
        super().__init__()
        self.latent = latent
        self.coarse_index = coarse_index
        self.mlp = Mlp(latent + n_query, 1, hidden)
        # Start from the coarse solution: zero correction.
        nn.init.zeros_(self.mlp.out.weight)
        nn.init.zeros_(self.mlp.out.bias)

    def first_bias(self, z):
        """z part of the first layer plus its bias: [B, H1]."""
        lin = self.mlp.linears[0]
        return z @ lin.weight[:, : self.latent].t() + lin.bias

    def hidden(self, bias, q):
        """Hidden activations for queries q [..., F] with per-row first-layer bias."""
        lin0 = self.mlp.linears[0]
        x = q @ lin0.weight[:, self.latent:].t() + bias
        x = torch.relu(self.mlp.norms[0](x))
        for lin, ln in zip(self.mlp.linears[1:], self.mlp.norms[1:]):
            x = torch.relu(ln(lin(x)))
        return x

    def forward_batched(self, z, q):
        """z [B, r], q [B, N, F] -> depth [B, N] (mm)."""
        bias = self.first_bias(z)[:, None, :]
        g = self.mlp.out(self.hidden(bias, q))[..., 0]
        return q[..., self.coarse_index] + g

    def forward(self, z, query):
        """ONNX signature: z [1, r], query [N, F] -> depth [N, 1] (mm)."""
        bias = self.first_bias(z)
        g = self.mlp.out(self.hidden(bias, query))
        return query[:, self.coarse_index : self.coarse_index + 1] + g


def _layer_norm_backward(dn, xhat, gamma, inv_sigma):
    dxhat = dn * gamma
    m1 = dxhat.mean(dim=-1, keepdim=True)
    m2 = (dxhat * xhat).mean(dim=-1, keepdim=True)
    return inv_sigma * (dxhat - m1 - xhat * m2)


class DecoderJacobian(nn.Module):
    """(z [1, r], query [N, F]) -> (depth [N, 1], jacobian [N, r] = d depth_i / d z)."""

    def __init__(self, decoder: Decoder):
        super().__init__()
        self.decoder = decoder

    def forward(self, z, query):
        dec = self.decoder
        mlp = dec.mlp
        lin0 = mlp.linears[0]
        a = query @ lin0.weight[:, dec.latent:].t() + dec.first_bias(z)
        cache = []
        x = a
        for k, (lin, ln) in enumerate(zip(mlp.linears, mlp.norms)):
            if k > 0:
                a = x @ lin.weight.t() + lin.bias
            mu = a.mean(dim=-1, keepdim=True)
            var = ((a - mu) ** 2).mean(dim=-1, keepdim=True)
            inv_sigma = 1.0 / torch.sqrt(var + ln.eps)
            xhat = (a - mu) * inv_sigma
            n = xhat * ln.weight + ln.bias
            mask = (n > 0).to(n.dtype)
            x = n * mask
            cache.append((xhat, inv_sigma, mask, ln.weight))
        depth = query[:, dec.coarse_index : dec.coarse_index + 1] + (x @ mlp.out.weight.t() + mlp.out.bias)
        # Backward, upstream 1 for every point separately.
        dx = mlp.out.weight.expand(x.shape[0], -1)
        for k in range(len(mlp.linears) - 1, -1, -1):
            xhat, inv_sigma, mask, gamma = cache[k]
            da = _layer_norm_backward(dx * mask, xhat, gamma, inv_sigma)
            if k > 0:
                dx = da @ mlp.linears[k].weight
        jac = da @ lin0.weight[:, : dec.latent]
        return depth, jac


def hidden_of(manifest):
    """A model directory's decoder widths (its manifest's `decoder_hidden`; the paper's before
    the manifest named them)."""
    return tuple(manifest.get("decoder_hidden", HIDDEN))


class Autoencoder(nn.Module):
    def __init__(self, n_enc: int, n_query: int, coarse_index: int, latent: int = 64,
                 decoder_hidden=HIDDEN):
        super().__init__()
        self.encoder = Encoder(n_enc, latent)
        self.decoder = Decoder(latent, n_query, coarse_index, decoder_hidden)
