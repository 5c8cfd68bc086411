"""Tiled pure-PyTorch rasterizer (CPU or CUDA) with an exact hand-written backward pass.

1. Binning: each visible Gaussian covers the tiles whose pixel centres fall in its exact extent
   (the box where alpha can reach 1/255, `Projected.extents`), so culling never drops a contribution.
2. Per-tile depth order: (camera, depth rank) pairs are emitted in depth order and stably sorted
   by tile, so every tile's list is front to back (the 3DGS key sort, without bit packing).
3. Compositing: tiles are grouped (by list length, longest first) into chunks of at most
   `max_elements` (pixel, Gaussian) pairs, each tile's list padded to the chunk's longest; alpha,
   cumulative-product transmittance, the 1/255 cut-off and the 1e-4 stop are evaluated on the
   whole (tiles, pixels, list) block at once.
4. Backward: recomputes each chunk (nothing per pair is kept between passes, so memory is bounded
   by one chunk) and applies the closed-form gradient of front-to-back compositing:
   dL/dalpha_i = T_i f_i - (sum_{k>i} w_k f_k) / (1 - alpha_i), f_k = <feat_k, dL/dC> + dL/dA.
"""

from __future__ import annotations

import torch

from seeu_model.rasterizer.projection import ALPHA_MAX, ALPHA_MIN, T_MIN, Projected

_MARGIN = 1e-3  # px added to extents: float rounding must never make culling drop a pixel


def bin_gaussians(proj: Projected, width: int, height: int, tile_size: int) -> tuple[torch.Tensor, torch.Tensor, int, int]:
    """Intersect Gaussians with tiles.

    Returns `isect_gauss` (I,) flat indices into C * N, `tile_ids` (I,) global tile index
    (camera * tiles_per_camera + row * tiles_x + col), both ordered by tile and, within a tile,
    front to back; and the tile grid size (tiles_x, tiles_y).
    """
    n_cam, n = proj.depths.shape
    tiles_x, tiles_y = -(-width // tile_size), -(-height // tile_size)
    dev = proj.depths.device
    with torch.no_grad():
        order = torch.sort(torch.where(proj.valid, proj.depths, torch.full_like(proj.depths, float("inf"))),
                           dim=-1, stable=True).indices  # (C, N)
        ext = torch.gather(proj.extents(), 1, order[..., None].expand(n_cam, n, 2)) + _MARGIN
        mean = torch.gather(proj.means2d.detach(), 1, order[..., None].expand(n_cam, n, 2))
        vis = torch.gather(proj.valid & (proj.opacities.detach() >= ALPHA_MIN), 1, order)
        # pixel columns j with |j + 0.5 - mx| <= ext_x, then their tiles (same for rows)
        lo = torch.ceil(mean - ext - 0.5)
        hi = torch.floor(mean + ext - 0.5)
        size = torch.tensor([width, height], device=dev, dtype=lo.dtype)
        vis = vis & (hi >= 0).all(-1) & (lo <= size - 1).all(-1) & (lo <= hi).all(-1)
        lo = torch.div(lo.clamp(min=0), tile_size, rounding_mode="floor").long()
        hi = torch.div(torch.minimum(hi, size - 1), tile_size, rounding_mode="floor").long()
        span = (hi - lo + 1).clamp(min=0)
        counts = (span[..., 0] * span[..., 1] * vis).reshape(-1)  # (C * N,) in (camera, depth rank) order
        total = int(counts.sum())
        src = torch.repeat_interleave(torch.arange(n_cam * n, device=dev), counts)  # (I,)
        starts = torch.cumsum(counts, 0) - counts
        k = torch.arange(total, device=dev) - starts[src]
        nx = span[..., 0].reshape(-1)[src]
        tx = lo[..., 0].reshape(-1)[src] + k % nx
        ty = lo[..., 1].reshape(-1)[src] + torch.div(k, nx, rounding_mode="floor")
        cam = torch.div(src, n, rounding_mode="floor")
        tile_ids = cam * (tiles_x * tiles_y) + ty * tiles_x + tx
        gauss = cam * n + order.reshape(-1)[src]
        tile_ids, perm = torch.sort(tile_ids, stable=True)
        return gauss[perm], tile_ids, tiles_x, tiles_y


def _plan_chunks(tile_counts: torch.Tensor, pixels_per_tile: int, max_elements: int) -> list[torch.Tensor]:
    """Group non-empty tiles, longest list first, so each chunk pads to at most `max_elements` pairs."""
    nonempty = torch.nonzero(tile_counts > 0).squeeze(1)
    if nonempty.numel() == 0:
        return []
    counts = tile_counts[nonempty]
    order = torch.sort(counts, descending=True, stable=True).indices
    tiles, counts = nonempty[order], counts[order].tolist()
    chunks, start = [], 0
    while start < len(counts):
        longest = counts[start]
        n_tiles = max(1, max_elements // max(1, longest * pixels_per_tile))
        chunks.append(tiles[start:start + n_tiles])
        start += n_tiles
    return chunks


class _Compositor:
    """Shared forward/backward state of one render (tiles, lists, pixel grid)."""

    def __init__(self, isect_gauss, tile_ids, n_tiles_total, tiles_x, tiles_y, tile_size, max_elements):
        self.isect_gauss = isect_gauss
        self.tile_counts = torch.bincount(tile_ids, minlength=n_tiles_total)
        self.tile_starts = torch.cumsum(self.tile_counts, 0) - self.tile_counts
        self.tiles_x, self.tiles_y, self.tile_size = tiles_x, tiles_y, tile_size
        self.n_tiles_total = n_tiles_total
        self.chunks = _plan_chunks(self.tile_counts, tile_size * tile_size, max_elements)
        dev = isect_gauss.device
        local = torch.arange(tile_size * tile_size, device=dev)
        self.local_xy = torch.stack([local % tile_size, torch.div(local, tile_size, rounding_mode="floor")], -1)

    def chunk_lists(self, tiles: torch.Tensor, dtype):
        """Padded Gaussian lists (T, L) and validity, plus pixel centres (T, P, 2) of `tiles`."""
        counts = self.tile_counts[tiles]
        longest = int(counts.max())
        ar = torch.arange(longest, device=tiles.device)
        valid = ar[None] < counts[:, None]  # (T, L)
        pos = torch.where(valid, self.tile_starts[tiles, None] + ar[None], torch.zeros_like(valid, dtype=torch.long))
        gidx = self.isect_gauss[pos]  # (T, L)
        in_cam = tiles % (self.tiles_x * self.tiles_y)
        origin = torch.stack([in_cam % self.tiles_x, torch.div(in_cam, self.tiles_x, rounding_mode="floor")], -1)
        pix = (origin[:, None, :] * self.tile_size + self.local_xy[None]).to(dtype) + 0.5  # (T, P, 2)
        return gidx, valid, pix


def _alpha_block(pix, mean, conic, opac, valid, alpha_max):
    """Per-pair quantities of a chunk. pix (T, P, 2); mean (T, L, 2); conic (T, L, 3); opac, valid (T, L).

    Returns dx, dy, gauss = exp(-power), raw = o * gauss, alpha (masked, clamped, stopped), T_before,
    all (T, P, L).
    """
    dx = pix[:, :, None, 0] - mean[:, None, :, 0]
    dy = pix[:, :, None, 1] - mean[:, None, :, 1]
    a, b, c = (conic[:, None, :, i] for i in range(3))
    power = dx * (0.5 * a * dx + b * dy) + 0.5 * c * dy * dy
    gauss = torch.exp(-power)
    raw = opac[:, None, :] * gauss
    alpha = raw.clamp(max=alpha_max)
    alpha = torch.where((power >= 0) & (alpha >= ALPHA_MIN) & valid[:, None, :], alpha, torch.zeros_like(alpha))
    trans = torch.cumprod(1.0 - alpha, dim=-1)
    alpha = torch.where(trans > T_MIN, alpha, torch.zeros_like(alpha))
    trans_before = torch.cat([torch.ones_like(trans[..., :1]), trans[..., :-1]], -1)
    return dx, dy, gauss, raw, alpha, trans_before


class _TiledComposite(torch.autograd.Function):
    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, comp: _Compositor, alpha_max: float):
        """means2d (M, 2), conics (M, 3), opacities (M,), feats (M, F), M = C * N.
        Returns per-tile features (tiles, P, F) and alpha (tiles, P)."""
        n_f = feats.shape[-1]
        n_pix = comp.tile_size ** 2
        out = means2d.new_zeros(comp.n_tiles_total, n_pix, n_f)
        out_a = means2d.new_zeros(comp.n_tiles_total, n_pix)
        for tiles in comp.chunks:
            gidx, valid, pix = comp.chunk_lists(tiles, means2d.dtype)
            _, _, _, _, alpha, trans_before = _alpha_block(pix, means2d[gidx], conics[gidx], opacities[gidx],
                                                           valid, alpha_max)
            w = alpha.mul_(trans_before)  # (T, P, L)
            out[tiles] = torch.bmm(w, feats[gidx])
            out_a[tiles] = w.sum(-1)
        ctx.save_for_backward(means2d, conics, opacities, feats)
        ctx.comp, ctx.alpha_max = comp, alpha_max
        return out, out_a

    @staticmethod
    def backward(ctx, g_out, g_alpha):
        means2d, conics, opacities, feats = ctx.saved_tensors
        comp, alpha_max = ctx.comp, ctx.alpha_max
        g_means = torch.zeros_like(means2d)
        g_conics = torch.zeros_like(conics)
        g_opac = torch.zeros_like(opacities)
        g_feats = torch.zeros_like(feats)
        g_out = g_out.contiguous()
        g_alpha = g_alpha.contiguous()
        for tiles in comp.chunks:
            gidx, valid, pix = comp.chunk_lists(tiles, means2d.dtype)
            mean, conic, opac, feat = means2d[gidx], conics[gidx], opacities[gidx], feats[gidx]
            dx, dy, gauss, raw, alpha, trans_before = _alpha_block(pix, mean, conic, opac, valid, alpha_max)
            w = alpha * trans_before  # (T, P, L)
            go, ga = g_out[tiles], g_alpha[tiles]  # (T, P, F), (T, P)
            g_feats.index_add_(0, gidx.reshape(-1), torch.bmm(w.transpose(1, 2), go).reshape(-1, feat.shape[-1]))
            f = torch.bmm(go, feat.transpose(1, 2)).add_(ga[..., None])  # (T, P, L) value of each contribution
            wf = w * f
            after = wf.sum(-1, keepdim=True) - torch.cumsum(wf, -1)  # sum_{k > i} w_k f_k
            g_alpha_pair = trans_before * f - after / (1.0 - alpha)
            # alpha = min(alpha_max, raw) where kept, else 0 (piecewise constant)
            g_raw = torch.where((alpha > 0) & (raw <= alpha_max), g_alpha_pair, torch.zeros_like(g_alpha_pair))
            g_opac.index_add_(0, gidx.reshape(-1), (g_raw * gauss).sum(1).reshape(-1))
            g_power = -(g_raw * raw)  # dL/dpower
            a, b, c = (conic[:, None, :, i] for i in range(3))
            g_dx = g_power * (a * dx + b * dy)
            g_dy = g_power * (b * dx + c * dy)
            g_mean = -torch.stack([g_dx.sum(1), g_dy.sum(1)], -1)  # (T, L, 2)
            g_conic = torch.stack([(0.5 * g_power * dx * dx).sum(1), (g_power * dx * dy).sum(1),
                                   (0.5 * g_power * dy * dy).sum(1)], -1)
            g_means.index_add_(0, gidx.reshape(-1), g_mean.reshape(-1, 2))
            g_conics.index_add_(0, gidx.reshape(-1), g_conic.reshape(-1, 3))
        return g_means, g_conics, g_opac, g_feats, None, None


def render_tiled(proj: Projected, width: int, height: int, tile_size: int = 16, alpha_max: float = ALPHA_MAX,
                 max_elements: int = 1 << 22) -> tuple[torch.Tensor, torch.Tensor]:
    """Render projected Gaussians with the tiled compositor.

    Returns features (C, H, W, 4) = (r, g, b, sum w z) and alpha (C, H, W), like `render_dense`.
    """
    if tile_size < 1:
        raise ValueError(f"tile_size must be >= 1, got {tile_size}")
    n_cam, n = proj.depths.shape
    isect_gauss, tile_ids, tiles_x, tiles_y = bin_gaussians(proj, width, height, tile_size)
    comp = _Compositor(isect_gauss, tile_ids, n_cam * tiles_x * tiles_y, tiles_x, tiles_y, tile_size, max_elements)
    feats = torch.cat([proj.colors, proj.depths[..., None]], -1).reshape(n_cam * n, 4)
    out, out_a = _TiledComposite.apply(proj.means2d.reshape(-1, 2), proj.conics.reshape(-1, 3),
                                       proj.opacities.reshape(-1), feats, comp, alpha_max)
    shape = (n_cam, tiles_y, tiles_x, tile_size, tile_size)
    out = out.reshape(*shape, 4).permute(0, 1, 3, 2, 4, 5).reshape(n_cam, tiles_y * tile_size, tiles_x * tile_size, 4)
    out_a = out_a.reshape(shape).permute(0, 1, 3, 2, 4).reshape(n_cam, tiles_y * tile_size, tiles_x * tile_size)
    return out[:, :height, :width], out_a[:, :height, :width]
