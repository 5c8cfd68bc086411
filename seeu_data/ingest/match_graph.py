"""The verified match graph of an SfM database, and the mapper `--mapper auto` picks from it.

Measurement (recorded in report.json under `sfm.mapper`): the verified image pairs with at least
`MIN_INLIERS` inlier matches, and from them the share of consecutive frames (in input order) that
are matched to each other. A video gives a chain: nearly every frame matches the next one
(100 % on the synthetic walk-through, which incremental mapping registers fully). Unordered
photos sorted by file name do not: neighbours in name order are often unrelated shots. `auto` then
picks incremental mapping for a chain (COLMAP's incremental mapper grows the model along it, the
best-tested path) and global mapping (GLOMAP's rotation averaging + global positioning, which does
not depend on an order) otherwise.

    stats = match_graph_stats(database, image_names)   # {"verified_pairs", "consecutive_matched_pct", ...}
    mapper, reason = choose_mapper(stats)
"""

from __future__ import annotations

import numpy as np

MIN_INLIERS = 15
CHAIN_PCT = 90.0  # consecutive frames matched, at or above which the input is treated as a video


def match_graph_stats(db, names: list[str]) -> dict:
    """Statistics of the verified match graph of `db` (an open pycolmap.Database) over `names`
    (the frames in input order)."""
    import pycolmap

    pos = {n: i for i, n in enumerate(names)}
    by_id = {img.image_id: pos.get(img.name) for img in db.read_all_images()}
    pair_ids, geoms = db.read_two_view_geometries()
    edges = set()
    for pid, g in zip(pair_ids, geoms):
        if len(g.inlier_matches) < MIN_INLIERS:
            continue
        a, b = (by_id.get(i) for i in pycolmap.pair_id_to_image_pair(pid))
        if a is not None and b is not None and a != b:
            edges.add((min(a, b), max(a, b)))
    n = len(names)
    chain = sum((i, i + 1) in edges for i in range(n - 1))
    gaps = np.array([b - a for a, b in edges]) if edges else np.zeros(0)
    degree = np.bincount(np.array([v for e in edges for v in e], np.int64), minlength=n) if edges else np.zeros(n)
    return {
        "verified_pairs": len(edges),
        "min_inliers": MIN_INLIERS,
        "consecutive_matched_pct": 100.0 * chain / max(n - 1, 1),
        "mean_index_gap": float(gaps.mean()) if len(gaps) else 0.0,
        "mean_degree": float(degree.mean()) if n else 0.0,
    }


def choose_mapper(stats: dict) -> tuple[str, str]:
    """('incremental' | 'global', why) from `match_graph_stats`."""
    pct = stats["consecutive_matched_pct"]
    if pct >= CHAIN_PCT:
        return "incremental", f"sequential input: {pct:.0f}% of consecutive frames matched (>= {CHAIN_PCT:.0f}%)"
    return "global", f"unordered input: only {pct:.0f}% of consecutive frames matched (< {CHAIN_PCT:.0f}%)"
