"""Compilation of the MPC predictor's Function to C, and the on-disk cache of compiled libraries.

``function_for(settings)`` builds the predictor's Function (``deck_sim.control.mpc_graph``) once per process
and settings and, unless ``settings.compile`` is "none", generates C for it, compiles it with the settings'
compiler and loads it (``compile_function``); a library is compiled once per machine and kept in the cache
directory (``default_cache_dir``). Without a working compiler the Function runs in CasADi's virtual machine
(``compile="auto"``) or the error propagates (``compile="c"``).
"""

from __future__ import annotations

import hashlib
import logging
import os
import platform
import shutil
import subprocess
import tempfile
import time
from pathlib import Path

import casadi as ca

from deck_sim.control.mpc_graph import build_function
from deck_sim.control.mpc_settings import MPCPredictorSettings

log = logging.getLogger(__name__)


def default_cache_dir() -> Path:
    """``$DECK_SIM_CACHE`` or ``$XDG_CACHE_HOME/deck_sim`` or ``~/.cache/deck_sim``, plus ``casadi``."""
    root = os.environ.get("DECK_SIM_CACHE")
    if root:
        return Path(root) / "casadi"
    xdg = os.environ.get("XDG_CACHE_HOME")
    return (Path(xdg) if xdg else Path.home() / ".cache") / "deck_sim" / "casadi"


def compile_function(
    fn: ca.Function, compiler: str, flags: tuple[str, ...], cache_dir: Path
) -> tuple[ca.Function, Path, bool]:
    """Generate C for ``fn``, compile it into ``cache_dir`` (once per hash), load it with ``casadi.external``.

    The cache key hashes the C source, compiler, flags, CasADi version and machine. The library is compiled
    into a temporary file and renamed into place, so concurrent processes never load a half-written file.

    Returns:
        (loaded Function, path of the shared library, whether it was compiled now rather than found cached).

    Raises:
        RuntimeError: if the compiler is missing or fails (its output is in the message).
    """
    cg = ca.CodeGenerator(f"{fn.name()}.c", {"with_header": False})
    cg.add(fn)
    source = cg.dump()
    key = hashlib.sha256(
        "\n".join(
            [source, compiler, " ".join(flags), ca.__version__, platform.machine(), platform.system()]
        ).encode()
    ).hexdigest()[:20]
    lib = cache_dir / f"{fn.name()}_{key}.so"
    if lib.exists():
        return ca.external(fn.name(), str(lib)), lib, False
    exe = shutil.which(compiler)
    if exe is None:
        raise RuntimeError(f"C compiler {compiler!r} not found on PATH")
    cache_dir.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=cache_dir) as tmp:
        src = Path(tmp) / f"{fn.name()}.c"
        src.write_text(source)
        out = Path(tmp) / "lib.so"
        proc = subprocess.run([exe, *flags, str(src), "-o", str(out), "-lm"], capture_output=True, text=True)
        if proc.returncode != 0:
            raise RuntimeError(f"{compiler} failed ({proc.returncode}): {proc.stderr.strip()[-2000:]}")
        os.replace(out, lib)
    return ca.external(fn.name(), str(lib)), lib, True


_FUNCTIONS: dict[MPCPredictorSettings, tuple[ca.Function, str, Path | None]] = {}
"""Functions already built in this process, by settings (a Function is stateless and may be shared)."""


def function_for(settings: MPCPredictorSettings) -> tuple[ca.Function, str, Path | None]:
    """(Function, backend "c" or "casadi-vm", shared library or None) of the predictor for ``settings``.

    Built once per process and settings; compiled once per machine (see ``compile_function``).
    """
    hit = _FUNCTIONS.get(settings)
    if hit is not None:
        return hit
    fn = build_function(settings)
    backend, library = "casadi-vm", None
    if settings.compile != "none":
        cache = Path(settings.cache_dir) if settings.cache_dir else default_cache_dir()
        try:
            t0 = time.perf_counter()
            fn, library, fresh = compile_function(fn, settings.compiler, settings.compiler_flags, cache)
            backend = "c"
            if fresh:
                log.info("MPC predictor compiled into %s in %.1f s", library, time.perf_counter() - t0)
            else:
                log.debug("MPC predictor loaded from %s", library)
        except (RuntimeError, OSError) as err:
            if settings.compile == "c":
                raise
            log.warning("MPC predictor: compilation unavailable (%s); using CasADi's virtual machine", err)
    _FUNCTIONS[settings] = (fn, backend, library)
    return fn, backend, library
