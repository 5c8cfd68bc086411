"""Connecting to Ray: the one `ray.init` of the toolkit (`seeu build --engine ray`, `seeu ingest --engine ray`).

    ensure_ray("10.0.0.5:6379")   # a running cluster; "auto" finds one; None (or "local") starts a local instance

`ray.init` keeps retrying an address where no Ray head answers for minutes (longer still when
something else listens on that port), printing warnings from its C++ core on stderr. So a given
address is checked first, and a failure is one line (`SeeUError`) within a bounded time:
  1. `host:port` must accept a TCP connection within `CONNECT_TIMEOUT_S` (no Ray needed: a refused
     port or an unknown host fails at once);
  2. a child process must complete `ray.init(address)` within `JOIN_TIMEOUT_S`; its output is kept
     from the user, only the error's last line is reported.
The check costs one Python start (about 2 s) per run that names an address.
"""

from __future__ import annotations

import logging
import os
import re
import socket
import subprocess
import sys
from pathlib import Path

from seeu_data.errors import SeeUError

CONNECT_TIMEOUT_S = 5.0
JOIN_TIMEOUT_S = 30.0

_JOIN = (
    "import logging, sys, ray\n"
    "ray.init(address=sys.argv[1], include_dashboard=False, logging_level=logging.ERROR, log_to_driver=False)\n"
    "ray.shutdown()\n"
)


def _host_port(address: str) -> tuple[str, int] | None:
    """'host:port', 'ray://host:port', '[::1]:6379' -> (host, port); None for 'auto', 'local' or no port."""
    text = address.split("://", 1)[-1].rstrip("/")
    host, sep, port = text.rpartition(":")
    if not sep or not port.isdigit() or not host:
        return None
    return host.strip("[]"), int(port)


def check_address(address: str, connect_s: float = CONNECT_TIMEOUT_S, join_s: float = JOIN_TIMEOUT_S) -> None:
    """Raise SeeUError unless a Ray cluster at `address` can be joined (see the module docstring)."""
    hp = _host_port(address)
    if hp is not None:
        try:
            with socket.create_connection(hp, timeout=connect_s):
                pass
        except OSError as exc:
            why = (
                f"no answer within {connect_s:g} s"
                if isinstance(exc, TimeoutError)
                else (exc.strerror or str(exc) or type(exc).__name__)
            )
            raise SeeUError(f"cannot reach the Ray cluster ({why})", address) from None
    try:
        proc = subprocess.run(
            [sys.executable, "-c", _JOIN, address], capture_output=True, text=True, timeout=join_s, env=os.environ
        )
    except subprocess.TimeoutExpired:
        raise SeeUError(
            f"no Ray cluster answered within {join_s:g} s (is this the head's GCS address, port 6379 by default?)",
            address,
        ) from None
    if proc.returncode != 0:
        raise SeeUError(f"cannot join the Ray cluster ({_join_error(proc.stderr, proc.returncode)})", address)


def _join_error(stderr: str, returncode: int) -> str:
    """The child's exception in one line: the last one raised, and its first cause when that differs
    (e.g. 'ConnectionError: Failed to connect ...; cause: ray.exceptions.AuthenticationError: ...')."""
    raised = [ln.strip() for ln in stderr.splitlines() if re.match(r"[A-Za-z_][\w.]*(Error|Exception)\b", ln)]
    if not raised:
        return f"exit {returncode}"
    first = raised[0].split(". ")[0]  # the first sentence: Ray's messages go on with advice
    return raised[-1] if len(raised) == 1 else f"{raised[-1]}; cause: {first}"


def ensure_ray(address: str | None = None) -> None:
    """Connect to `address` (a running cluster, 'auto') or start a local instance when none is up.

    Does nothing when Ray is already initialised in this process (whatever `address` says).
    Raises SeeUError (one line) when the cluster cannot be reached or Ray cannot start.
    """
    import ray

    if ray.is_initialized():
        return
    if address not in (None, "local"):  # "local": start a new local instance, as None does
        check_address(address)
    repo_root = str(Path(__file__).resolve().parent.parent)
    try:
        ray.init(
            address=address,
            include_dashboard=False,
            logging_level=logging.ERROR,
            log_to_driver=False,
            runtime_env={"env_vars": {"PYTHONPATH": repo_root}},
        )
    except (ConnectionError, ValueError, RuntimeError) as exc:
        raise SeeUError(f"cannot start or reach Ray ({str(exc).splitlines()[0]})", address or "local") from None
