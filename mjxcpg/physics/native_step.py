"""MuJoCo C stepped inside XLA (``mujoco_step.cc``, an XLA FFI handler), with no Python in
the control period: what makes small batches cheap on the native engine.

The handler is compiled on first use with the machine's C++ compiler against the headers of
the installed MuJoCo and jaxlib, and cached (``MJXCPG_CACHE``, else ``$XDG_CACHE_HOME/mjxcpg``
or ``~/.cache/mjxcpg``) under a name that hashes its source and both versions.  Without a
compiler, or if the build fails, ``step_handler()`` says why once and returns None, and the
native engine keeps its Python host callback: the same MuJoCo calls, so the same results.
"""

from __future__ import annotations

import ctypes
import functools
import hashlib
import importlib.resources
import os
import shutil
import subprocess
import sys
import tempfile
from pathlib import Path

import jax
import mujoco

TARGET = "mjxcpg_mujoco_step"
SYMBOL = "MjxcpgMujocoStep"
DISABLE = "MJXCPG_NO_FFI"  # set (to anything) to keep the Python host callback


def cache_dir() -> Path:
    explicit = os.environ.get("MJXCPG_CACHE")
    if explicit:
        return Path(explicit)
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "mjxcpg"


def _library_name(source: bytes) -> str:
    key = hashlib.sha256(source + mujoco.__version__.encode() + jax.__version__.encode()
                         + sys.platform.encode()).hexdigest()[:16]
    return f"mujoco_step_{key}.so"


def _build(source: bytes, target: Path) -> None:
    """Compile ``source`` into the shared library ``target`` (atomically: a half-written
    library is never loaded)."""
    compiler = os.environ.get("CXX") or shutil.which("c++") or shutil.which("g++")
    if compiler is None:
        raise RuntimeError("no C++ compiler (c++, g++ or $CXX)")
    mujoco_dir = Path(mujoco.__file__).parent
    libraries = sorted(mujoco_dir.glob("libmujoco.so*"))
    if not libraries:
        raise RuntimeError(f"no libmujoco.so in {mujoco_dir}")
    target.parent.mkdir(parents=True, exist_ok=True)
    with tempfile.TemporaryDirectory(dir=target.parent) as folder:
        cc, out = Path(folder) / "mujoco_step.cc", Path(folder) / target.name
        cc.write_bytes(source)
        command = [compiler, "-O2", "-std=c++17", "-pthread", "-shared", "-fPIC", "-o", str(out), str(cc),
                   f"-I{jax.ffi.include_dir()}", f"-I{mujoco_dir / 'include'}",
                   str(libraries[0]), f"-Wl,-rpath,{mujoco_dir}"]
        result = subprocess.run(command, capture_output=True, text=True)
        if result.returncode != 0:
            last = (result.stderr.strip().splitlines() or ["(no output)"])[-1]
            raise RuntimeError(f"the compiler failed: {last}")
        os.replace(out, target)


@functools.cache
def step_handler() -> str | None:
    """The FFI target's name, registered with JAX for the CPU, or None (with a one-line notice
    on stderr) when it cannot be built or is switched off with ``MJXCPG_NO_FFI``."""
    if os.environ.get(DISABLE):
        return None
    try:
        source = importlib.resources.files("mjxcpg.physics").joinpath("mujoco_step.cc").read_bytes()
        library = cache_dir() / _library_name(source)
        if not library.is_file():
            _build(source, library)
        handle = ctypes.cdll.LoadLibrary(str(library))
        jax.ffi.register_ffi_target(TARGET, jax.ffi.pycapsule(getattr(handle, SYMBOL)), platform="cpu")
    except (OSError, RuntimeError, AttributeError) as error:
        print(f"mjxcpg: MuJoCo C runs through a Python callback (slower at small batches): {error}",
              file=sys.stderr)
        return None
    return TARGET
