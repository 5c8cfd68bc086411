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


def bin_gaussians(
    proj: Projected, width: int, height: int, tile_size: int
) -> tuple[torch.Tensor, torch.Tensor, int, int]:
    """Intersect Gaussians with tiles.

    Returns `isect_gauss` (I,) flat indices into C * N, `tile_ids` (I,) global tile index
    (camera * tiles_per_camera + row * tiles_x + col), both ordered by tile and, within a tile,
    front to back; and the tile grid size (tiles_x, tiles_y).
    """
    n_cam, n = proj.depths.shape
    tiles_x, tiles_y = -(-width // tile_size), -(-height // tile_size)
    dev = proj.depths.device
    with torch.no_grad():
        order = torch.sort(
            torch.where(proj.valid, proj.depths, torch.full_like(proj.depths, float("inf"))), dim=-1, stable=True
        ).indices  # (C, N)
        ext = torch.gather(proj.extents(), 1, order[..., None].expand(n_cam, n, 2)) * (1 + 1e-5) + _MARGIN
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
    tiles = nonempty[order]
    sizes: list[int] = counts[order].tolist()
    chunks: list[torch.Tensor] = []
    start = 0
    while start < len(sizes):
        longest = sizes[start]
        n_tiles = max(1, max_elements // max(1, longest * pixels_per_tile))
        chunks.append(tiles[start : start + n_tiles])
        start += n_tiles
    return chunks


class TileCompositor:
    """Shared forward/backward state of one render (tiles, lists, pixel grid)."""

    def __init__(self, isect_gauss, tile_ids, n_tiles_total, tiles_x, tiles_y, tile_size, max_elements):
        self.isect_gauss = isect_gauss
        self.tile_counts = torch.bincount(tile_ids, minlength=n_tiles_total)
        self.tile_starts = torch.cumsum(self.tile_counts, 0) - self.tile_counts
        self.tiles_x, self.tiles_y, self.tile_size = tiles_x, tiles_y, tile_size
        self.n_tiles_total = n_tiles_total
        self.chunks = _plan_chunks(self.tile_counts, tile_size * tile_size, max_elements)
        local = torch.arange(tile_size * tile_size, device=isect_gauss.device)
        # pixel-centre offsets from the tile centre, (P, 2)
        self.local_xy = torch.stack([local % tile_size, torch.div(local, tile_size, rounding_mode="floor")], -1)
        self.local_xy = self.local_xy + 0.5 - 0.5 * tile_size

    def chunk_lists(self, tiles: torch.Tensor):
        """Padded Gaussian lists (T, L) of `tiles` (padding points at Gaussian 0, flagged in `pad`)
        and the tile centres (T, 2) in pixels."""
        counts = self.tile_counts[tiles]
        ar = torch.arange(int(counts.max()), device=tiles.device)
        pad = ar[None] >= counts[:, None]  # (T, L)
        pos = (self.tile_starts[tiles, None] + ar[None]).masked_fill_(pad, 0)
        in_cam = tiles % (self.tiles_x * self.tiles_y)
        origin = torch.stack([in_cam % self.tiles_x, torch.div(in_cam, self.tiles_x, rounding_mode="floor")], -1)
        return self.isect_gauss[pos], pad, origin * self.tile_size + 0.5 * self.tile_size


def _gather(table: torch.Tensor, gidx: torch.Tensor, pad: torch.Tensor, centre: torch.Tensor):
    """Per-Gaussian parameters of a chunk from the (M, 6) table (mx, my, a, b, c, o): means relative
    to the tile centre (T, L, 2), conic (T, L, 3) and opacity (T, L) (0 on padding)."""
    g = table[gidx]  # (T, L, 6)
    mean = g[..., :2] - centre[:, None, :]
    return mean, g[..., 2:5], g[..., 5].masked_fill(pad, 0.0)


def _composite_block(local, mean, conic, opac, alpha_max, need_backward):
    """Front-to-back compositing of one chunk.

    local (P, 2) pixel offsets from the tile centre; mean (T, L, 2) relative to the tile centre;
    conic (T, L, 3); opac (T, L). Returns weights w (T, P, L); with `need_backward` also
    gauss = exp(-power), the kept-and-unclamped mask, T before each Gaussian and 1 - alpha.
    """
    dx = local[None, :, None, 0] - mean[:, None, :, 0]  # (T, P, L)
    dy = local[None, :, None, 1] - mean[:, None, :, 1]
    a, b, c = (conic[:, None, :, i] for i in range(3))
    power = dx * (0.5 * a)
    power.mul_(dx)
    tmp = dy * b
    power.addcmul_(tmp, dx)
    torch.mul(dy, 0.5 * c, out=tmp)
    power.addcmul_(tmp, dy)
    del dx, dy, tmp
    gauss = power.neg_().exp_()  # in place: power is not needed any more
    alpha = gauss * opac[:, None, :] if need_backward else gauss.mul_(opac[:, None, :])
    clamped = alpha > alpha_max if need_backward else None
    alpha.clamp_(max=alpha_max)
    alpha.masked_fill_(alpha < ALPHA_MIN, 0.0)
    t_pl, p_pl, l_pl = alpha.shape
    one_minus = alpha.new_empty(t_pl, p_pl, l_pl + 1)
    one_minus[..., 0] = 1.0
    torch.sub(1.0, alpha, out=one_minus[..., 1:])
    trans = torch.cumprod(one_minus, dim=-1)  # trans[..., i] = T before Gaussian i; [..., i + 1] after
    alpha.masked_fill_(trans[..., 1:] <= T_MIN, 0.0)
    trans_before = trans[..., :-1]
    if not need_backward:
        return alpha.mul_(trans_before), None, None, None, None
    live = (alpha > 0).logical_and_(clamped.logical_not_())
    return alpha * trans_before, gauss, live, trans_before, one_minus[..., 1:]


class TiledComposite(torch.autograd.Function):
    """Front-to-back alpha compositing of the per-tile Gaussian lists, with its own backward pass."""

    @staticmethod
    def forward(ctx, means2d, conics, opacities, feats, comp: TileCompositor, alpha_max: float):
        """means2d (M, 2), conics (M, 3), opacities (M,), feats (M, F), M = C * N.
        Returns per-tile features (tiles, P, F) and alpha (tiles, P)."""
        n_pix = comp.tile_size**2
        table = torch.cat([means2d, conics, opacities[:, None]], -1)
        local = comp.local_xy.to(means2d.dtype)
        out = means2d.new_zeros(comp.n_tiles_total, n_pix, feats.shape[-1])
        out_a = means2d.new_zeros(comp.n_tiles_total, n_pix)
        for tiles in comp.chunks:
            gidx, pad, centre = comp.chunk_lists(tiles)
            mean, conic, opac = _gather(table, gidx, pad, centre)
            w, *_ = _composite_block(local, mean, conic, opac, alpha_max, need_backward=False)
            out[tiles] = torch.bmm(w, feats[gidx])
            out_a[tiles] = w.sum(-1)
        ctx.save_for_backward(table, feats)
        ctx.comp, ctx.alpha_max = comp, alpha_max
        return out, out_a

    @staticmethod
    def backward(ctx, g_out, g_alpha):
        table, feats = ctx.saved_tensors
        comp, alpha_max = ctx.comp, ctx.alpha_max
        local = comp.local_xy.to(table.dtype)
        n_f = feats.shape[-1]
        # moments basis (P, 6): 1, u, v, u^2, u v, v^2 with (u, v) the pixel offset from the tile centre
        u, v = local[:, 0], local[:, 1]
        basis_t = torch.stack([torch.ones_like(u), u, v, u * u, u * v, v * v], 0)  # (6, P)
        g_table = torch.zeros_like(table)  # (M, 6): d/d(mx, my, a, b, c, o)
        g_feats = torch.zeros_like(feats)
        g_out = g_out.contiguous()
        g_alpha = g_alpha.contiguous()
        for tiles in comp.chunks:
            gidx, pad, centre = comp.chunk_lists(tiles)
            mean, conic, opac = _gather(table, gidx, pad, centre)
            feat = feats[gidx]  # (T, L, F)
            w, gauss, live, trans_before, one_minus = _composite_block(local, mean, conic, opac, alpha_max, True)
            go, ga = g_out[tiles], g_alpha[tiles]  # (T, P, F), (T, P)
            flat = gidx.reshape(-1)
            g_feats.index_add_(0, flat, torch.bmm(w.transpose(1, 2), go).reshape(-1, n_f))
            f = torch.baddbmm(ga[..., None], go, feat.transpose(1, 2))  # (T, P, L): <feat_i, dC> + dA
            wf = w.mul_(f)
            after = torch.cumsum(wf, -1).neg_().add_(wf.sum(-1, keepdim=True))  # sum_{k > i} w_k f_k
            g_alpha_pair = f.mul_(trans_before).sub_(after.div_(one_minus))
            q = g_alpha_pair.mul_(live).mul_(gauss)  # dL/d(raw alpha) * exp(-power)
            # dL/dpower = -o q; its moments over the pixels give the mean and conic gradients
            mom = torch.bmm(basis_t.expand(q.shape[0], 6, -1), q) * (-opac[:, None, :])  # (T, 6, L)
            s1, su, sv, suu, suv, svv = mom.unbind(1)
            mx, my = mean.unbind(-1)
            a, b, c = conic.unbind(-1)
            sdx, sdy = su - mx * s1, sv - my * s1  # sum g_power dx, sum g_power dy
            sdxx = suu - 2 * mx * su + mx * mx * s1
            sdxy = suv - mx * sv - my * su + mx * my * s1
            sdyy = svv - 2 * my * sv + my * my * s1
            g_chunk = torch.stack(
                [-(a * sdx + b * sdy), -(b * sdx + c * sdy), 0.5 * sdxx, sdxy, 0.5 * sdyy, q.sum(1)], -1
            )  # (T, L, 6)
            g_table.index_add_(0, flat, g_chunk.masked_fill_(pad[..., None], 0.0).reshape(-1, 6))
        g_means, g_conics, g_opac = g_table.split([2, 3, 1], -1)
        return g_means, g_conics, g_opac.squeeze(-1), g_feats, None, None


def render_tiled(
    proj: Projected,
    width: int,
    height: int,
    tile_size: int = 16,
    alpha_max: float = ALPHA_MAX,
    max_elements: int = 1 << 22,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Render projected Gaussians with the tiled compositor.

    Returns features (C, H, W, 4) = (r, g, b, sum w z) and alpha (C, H, W), like `render_dense`.
    """
    if tile_size < 1:
        raise ValueError(f"tile_size must be >= 1, got {tile_size}")
    n_cam, n = proj.depths.shape
    isect_gauss, tile_ids, tiles_x, tiles_y = bin_gaussians(proj, width, height, tile_size)
    comp = TileCompositor(isect_gauss, tile_ids, n_cam * tiles_x * tiles_y, tiles_x, tiles_y, tile_size, max_elements)
    feats = torch.cat([proj.colors, proj.depths[..., None]], -1).reshape(n_cam * n, 4)
    out, out_a = TiledComposite.apply(
        proj.means2d.reshape(-1, 2), proj.conics.reshape(-1, 3), proj.opacities.reshape(-1), feats, comp, alpha_max
    )
    shape = (n_cam, tiles_y, tiles_x, tile_size, tile_size)
    out = out.reshape(*shape, 4).permute(0, 1, 3, 2, 4, 5).reshape(n_cam, tiles_y * tile_size, tiles_x * tile_size, 4)
    out_a = out_a.reshape(shape).permute(0, 1, 3, 2, 4).reshape(n_cam, tiles_y * tile_size, tiles_x * tile_size)
    return out[:, :height, :width], out_a[:, :height, :width]
