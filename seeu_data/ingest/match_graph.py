"""Which frame pairs SfM matches (`--matcher auto`), the verified match graph of an SfM database, and
the mapper `--mapper auto` picks from it.

Matcher (`choose_matcher`, recorded in report.json under `sfm.matcher`): a video is matched
sequentially (its frames are ordered: frames 1, 2, 4, ... apart, `--overlap`). An image folder may
be unordered (photos named in any order), so it is matched exhaustively (every pair, n (n - 1) / 2
of them) up to `EXHAUSTIVE_MAX_IMAGES` images; above that, without an image-retrieval index, each
image is matched with the next `UNORDERED_OVERLAP` images in name order (photos from one camera are
numbered in shooting order, so neighbours in name usually overlap). COLMAP's vocabulary-tree
matcher would find the overlapping pairs of a large unordered folder instead, but needs a
vocabulary-tree file in the format of the installed COLMAP (a download from COLMAP's GitHub
releases, e.g. the 256K-word tree trained on Flickr100K, `vocab_tree_faiss_flickr100K_words256K.bin`
for COLMAP >= 3.12; pycolmap's `match_vocabtree` with `VocabTreePairingOptions.vocab_tree_path`, whose
default here is unset); it is not used. `--vocab-tree FILE` adds loop detection to sequential matching.

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
# An image folder of up to this many images is matched exhaustively (150: 11,175 pairs; matching one
# pair of 8192 SIFT features takes ~10 ms on a CPU core, so about 2 minutes on one thread)
EXHAUSTIVE_MAX_IMAGES = 150
# Above it, each image is matched with this many next images in name order
UNORDERED_OVERLAP = 40
# An image folder of more images than this (up to EXHAUSTIVE_MAX_IMAGES) is matched on the pairs that
# share enough of the images' most prominent features (`seeu_data.ingest.pairs.shortlist_pairs`)
SHORTLIST_ABOVE = 30
CHAIN_PCT = 90.0  # consecutive frames matched, at or above which the input is treated as a video


def match_graph_stats(db, names: list[str]) -> dict:
    """Statistics of the verified match graph of `db` (an open pycolmap.Database) over `names`
    (the frames in input order)."""
    import pycolmap

    pos = {n: i for i, n in enumerate(names)}
    by_id = {img.image_id: pos.get(img.name) for img in db.read_all_images()}
    pair_ids, geoms = db.read_two_view_geometries()
    edges = set()
    inliers = []
    for pid, g in zip(pair_ids, geoms):
        if len(g.inlier_matches) < MIN_INLIERS:
            continue
        a, b = (by_id.get(i) for i in pycolmap.pair_id_to_image_pair(pid))
        if a is not None and b is not None and a != b:
            edges.add((min(a, b), max(a, b)))
            inliers.append(len(g.inlier_matches))
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
        "median_inliers": float(np.median(inliers)) if inliers else 0.0,
    }


def choose_mapper(stats: dict) -> tuple[str, str]:
    """('incremental' | 'global', why) from `match_graph_stats`."""
    pct = stats["consecutive_matched_pct"]
    if pct >= CHAIN_PCT:
        return "incremental", f"sequential input: {pct:.0f}% of consecutive frames matched (>= {CHAIN_PCT:.0f}%)"
    return "global", f"unordered input: only {pct:.0f}% of consecutive frames matched (< {CHAIN_PCT:.0f}%)"


def choose_matcher(requested: str, video: bool, num_images: int, overlap: int) -> dict:
    """The matching `requested` (auto, exhaustive or sequential) resolved for `num_images` frames of a
    video (`video`) or an image folder: {"requested", "used" (exhaustive | sequential), "overlap",
    "quadratic" (sequential pairs 1, 2, 4, ..., 2**(overlap-1) apart, else the next `overlap`),
    "shortlist" (exhaustive over the pairs `seeu_data.ingest.pairs.shortlist_pairs` keeps), "reason"}."""
    used, quadratic, why, shortlist = requested, True, "requested", False
    if requested == "auto" and video:
        used, why = "sequential", "a video: ordered frames"
    elif requested == "auto" and num_images <= SHORTLIST_ABOVE:
        used, why = "exhaustive", f"an image folder of {num_images} <= {SHORTLIST_ABOVE} images: every pair"
    elif requested == "auto" and num_images <= EXHAUSTIVE_MAX_IMAGES:
        used, shortlist = "exhaustive", True
        why = (
            f"an image folder of {num_images} <= {EXHAUSTIVE_MAX_IMAGES} images: every pair that shares enough "
            "of the images' most prominent features"
        )
    elif requested == "auto":
        used, quadratic, overlap = "sequential", False, UNORDERED_OVERLAP
        why = (
            f"an image folder of {num_images} > {EXHAUSTIVE_MAX_IMAGES} images: each with the next "
            f"{UNORDERED_OVERLAP} in name order"
        )
    return {
        "requested": requested,
        "used": used,
        "overlap": overlap if used == "sequential" else None,
        "quadratic": quadratic if used == "sequential" else False,
        "shortlist": shortlist,
        "reason": why,
    }
