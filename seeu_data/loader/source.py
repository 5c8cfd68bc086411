"""Where the shards live: a local directory or object storage (pyarrow.fs), with a bounded local cache.

`ShardSource(url)` reads and checks the dataset's `manifest.json` (schema `seeu.triples`) and hands
out local, verified paths of its shard files (`local_path(k)`), which the reader memory-maps.

* Local directory (`/data/re10k-triples` or `file:///...`): the files are used in place. Each shard's
  size is checked on every open and its sha256 on the first read. A verified file is remembered in
  this process and, when there is a cache directory (`cache_dir`, else `$SEEU_CACHE_DIR/loader`;
  `seeu train` uses OUT/cache), in `cache_dir/verified/<manifest sha256>`, keyed by the file's path,
  size, inode, mtime and ctime: a rewrite in place or a replacement changes the inode or the ctime
  (which no user call can set back), so it is hashed again. Without a cache directory the stamps
  live only in this process.
* Object storage (`s3://bucket/prefix`, `gs://...`, anything `pyarrow.fs.FileSystem.from_uri` opens;
  S3 options such as `?endpoint_override=host:port&scheme=http` go in the URL, credentials come from
  the usual environment): whole shards are downloaded into `cache_dir/objects/<sha256>.arrow`
  (content-addressed, so a changed dataset never reads a stale file), hashed while downloading,
  written to a temporary name and renamed, under a per-shard file lock so the workers of a machine
  download each shard once. The cache is bounded by `cache_limit_bytes`: least recently used shards
  are evicted first (POSIX keeps a memory-mapped file readable after it is unlinked, so eviction
  never breaks a reader; a cache smaller than one shard is allowed and just re-downloads).
"""

from __future__ import annotations

import fcntl
import hashlib
import os
import time
import warnings
from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass
from pathlib import Path

from seeu_data.errors import SeeUError
from seeu_data.store.arrow_io import sha256_file
from seeu_data.store.manifest import MANIFEST_NAME, read_manifest

SCHEMA = "seeu.triples"
DEFAULT_CACHE_LIMIT = 64 << 30  # 64 GiB
_VERIFIED: set[tuple] = set()  # (sha256, path, size, inode, mtime_ns, ctime_ns) hashed in this process


def default_cache_dir() -> Path:
    """`$SEEU_CACHE_DIR/loader`, else `~/.cache/seeu/loader` (object-storage downloads only)."""
    base = os.environ.get("SEEU_CACHE_DIR")
    return (Path(base) if base else Path.home() / ".cache" / "seeu") / "loader"


def _stamp_dir(cache_dir: str | Path | None) -> Path | None:
    """Where verification stamps of local shards go: the cache dir the user chose, else none."""
    if cache_dir is not None:
        return Path(cache_dir) / "verified"
    base = os.environ.get("SEEU_CACHE_DIR")
    return Path(base) / "loader" / "verified" if base else None


@dataclass(frozen=True)
class ShardInfo:
    """One shard file as listed in the manifest."""

    index: int
    path: str  # relative to the dataset root
    rows: int
    bytes: int
    sha256: str


@contextmanager
def _file_lock(path: Path) -> Iterator[None]:
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as fh:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX)
        try:
            yield
        finally:
            fcntl.flock(fh.fileno(), fcntl.LOCK_UN)


def _is_remote(url: str) -> bool:
    return "://" in url and not url.startswith("file://")


class ShardSource:
    """The manifest and shard files of a triples dataset at `url` (local path or object-storage URI)."""

    def __init__(
        self,
        url: str | Path,
        cache_dir: str | Path | None = None,
        cache_limit_bytes: int = DEFAULT_CACHE_LIMIT,
        verify: str = "sha256",
        filesystem=None,
    ):
        if verify not in ("sha256", "size"):
            raise ValueError("verify must be 'sha256' or 'size'")
        self.uri = str(url)  # as given (object-storage options may follow '?')
        self.url = self.uri.split("?", 1)[0].rstrip("/")  # for messages and cache keys
        self.cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self.stamp_dir = _stamp_dir(cache_dir)
        self.cache_limit_bytes = int(cache_limit_bytes)
        self.verify = verify
        self.remote = filesystem is not None or _is_remote(self.url)
        self._fs = filesystem
        if self.remote:
            if self._fs is None:
                import pyarrow.fs as pafs

                try:
                    self._fs, self._root = pafs.FileSystem.from_uri(self.uri)
                except Exception as exc:  # noqa: BLE001 - pyarrow raises several types
                    raise SeeUError(f"cannot open object storage: {exc}".splitlines()[0], self.url) from None
            else:
                self._root = self.url.split("://", 1)[-1]
            self._root = self._root.rstrip("/")
            self.root = self.cache_dir / "manifests" / hashlib.sha1(self.uri.encode()).hexdigest()[:16]
            self._fetch_manifest()
        else:
            self.root = Path(self.url[len("file://") :] if self.url.startswith("file://") else self.url)
        self.manifest = read_manifest(self.root, expect_schema=SCHEMA)
        self.shards = [
            ShardInfo(i, f["path"], int(f["rows"]), int(f["bytes"]), f["sha256"])
            for i, f in enumerate(self.manifest["files"])
        ]

    # ------------------------------------------------------------------ naming
    def name(self, k: int) -> str:
        """The shard as users know it (for error messages): URL or path."""
        return f"{self.url}/{self.shards[k].path}"

    # ------------------------------------------------------------------ local files
    def local_path(self, k: int) -> Path:
        """A local, verified copy of shard k (the file itself for local datasets)."""
        info = self.shards[k]
        return self._fetch(info) if self.remote else self._check_local(info)

    def _check_local(self, info: ShardInfo) -> Path:
        path = (self.root / info.path).resolve()
        try:
            st = path.stat()
        except FileNotFoundError:
            raise SeeUError("shard listed in the manifest is missing", path) from None
        if st.st_size != info.bytes:
            raise SeeUError(
                f"size {st.st_size} bytes differs from the manifest's {info.bytes} (truncated or replaced?)", path
            )
        if self.verify == "sha256":
            key = (info.sha256, str(path), st.st_size, st.st_dev, st.st_ino, st.st_mtime_ns, st.st_ctime_ns)
            if key not in _VERIFIED:
                marker = self.stamp_dir / info.sha256 if self.stamp_dir is not None else None
                stamp = "\t".join(str(v) for v in key)
                try:
                    known = marker is not None and marker.read_text() == stamp
                except OSError:
                    known = False
                if not known:
                    if sha256_file(path) != info.sha256:
                        raise SeeUError("sha256 differs from the manifest (corrupt or replaced)", path)
                    if marker is not None:
                        try:
                            marker.parent.mkdir(parents=True, exist_ok=True)
                            tmp = marker.with_name(f".{marker.name}.{os.getpid()}.tmp")
                            tmp.write_text(stamp)
                            os.replace(tmp, marker)
                        except OSError:
                            pass  # a read-only cache only costs re-hashing
                _VERIFIED.add(key)
        return path

    # ------------------------------------------------------------------ object storage
    def _fetch_manifest(self) -> None:
        try:
            with self._fs.open_input_stream(f"{self._root}/{MANIFEST_NAME}") as fh:
                data = fh.read()
        except FileNotFoundError:
            raise SeeUError("no manifest.json: not a SeeU dataset, or its write did not finish", self.url) from None
        except OSError as exc:
            raise SeeUError(f"cannot read the manifest: {exc}".splitlines()[0], self.url) from None
        self.root.mkdir(parents=True, exist_ok=True)
        tmp = self.root / f".{MANIFEST_NAME}.{os.getpid()}.tmp"
        tmp.write_bytes(data)
        os.replace(tmp, self.root / MANIFEST_NAME)

    def _fetch(self, info: ShardInfo) -> Path:
        objects = self.cache_dir / "objects"
        dest = objects / f"{info.sha256}.arrow"
        with _file_lock(objects / f".{info.sha256}.lock"):
            st = dest.stat() if dest.exists() else None
            if st is not None and st.st_size == info.bytes:
                # LRU stamp in the access time: the mtime stays, as a worker reading the file checks it (ShardReader)
                os.utime(dest, ns=(time.time_ns(), st.st_mtime_ns))
                return dest
            self._make_room(objects, info.bytes, keep=dest)
            tmp = objects / f".{info.sha256}.{os.getpid()}.tmp"
            digest = hashlib.sha256()
            size = 0
            try:
                with self._fs.open_input_stream(f"{self._root}/{info.path}") as src, open(tmp, "wb") as out:
                    while block := src.read(1 << 22):
                        digest.update(block)
                        out.write(block)
                        size += len(block)
                if size != info.bytes:
                    raise SeeUError(
                        f"downloaded {size} bytes, the manifest says {info.bytes} (truncated or replaced?)",
                        self.name(info.index),
                    )
                if digest.hexdigest() != info.sha256:
                    raise SeeUError(
                        "sha256 of the downloaded shard differs from the manifest (corrupt or replaced)",
                        self.name(info.index),
                    )
                os.replace(tmp, dest)
            except FileNotFoundError:
                raise SeeUError("shard listed in the manifest is missing", self.name(info.index)) from None
            except OSError as exc:
                raise SeeUError(f"download failed: {exc}".splitlines()[0], self.name(info.index)) from None
            finally:
                tmp.unlink(missing_ok=True)
        return dest

    def _make_room(self, objects: Path, need: int, keep: Path) -> None:
        """Evict least recently used cached shards until `need` more bytes fit under the limit."""
        with _file_lock(objects / ".evict.lock"):
            files = []
            for p in objects.glob("*.arrow"):
                try:
                    st = p.stat()
                except FileNotFoundError:
                    continue
                files.append((st.st_atime_ns, st.st_size, p))
            used = sum(f[1] for f in files)
            for _, size, p in sorted(files):
                if used + need <= self.cache_limit_bytes:
                    break
                if p == keep:
                    continue
                p.unlink(missing_ok=True)
                used -= size
            if used + need > self.cache_limit_bytes:
                warnings.warn(
                    f"seeu loader cache {objects} is smaller than one shard ({need} bytes); "
                    "shards will be downloaded again when re-read",
                    stacklevel=3,
                )
