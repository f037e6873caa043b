"""Which code made a run: what decides its numbers, recorded in its config.json.

The identity is the package's version, a sha256 of its Python sources, a sha256 of the robot
model, and the versions of the libraries that compute (JAX, MuJoCo, NumPy, orbax).  The git
commit is recorded where there is one, but not compared: a commit also changes with the docs,
and a working tree may differ from its commit.
"""

from __future__ import annotations

import hashlib
import importlib.metadata
import subprocess
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parents[1]  # the whole mjxcpg package, not this layer
MODEL_DIR = PACKAGE_DIR  # the robot models ship inside the package: every *.xml under it
LIBRARIES = ("mjxcpg", "jax", "jaxlib", "mujoco", "mujoco-mjx", "numpy", "orbax-checkpoint")
# The keys of ``code_identity`` that must agree for a run to be resumed.
COMPARED = ("versions", "source_sha256", "model_sha256")


def files_sha256(root: Path, pattern: str) -> str:
    """One sha256 over the files under ``root`` matching ``pattern``: names and contents, in
    name order, so that a renamed file changes it too."""
    digest = hashlib.sha256()
    for path in sorted(root.rglob(pattern)):
        digest.update(path.relative_to(root).as_posix().encode() + b"\0")
        digest.update(path.read_bytes() + b"\0")
    return digest.hexdigest()


def git_commit(root: Path) -> str | None:
    """The commit checked out at ``root``, or None outside a git work tree."""
    try:
        result = subprocess.run(["git", "-C", str(root), "rev-parse", "HEAD"], capture_output=True,
                                text=True, timeout=10, check=True)
    except (OSError, subprocess.SubprocessError):
        return None
    return result.stdout.strip() or None


def library_versions() -> dict[str, str | None]:
    versions = {}
    for name in LIBRARIES:
        try:
            versions[name] = importlib.metadata.version(name)
        except importlib.metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def code_identity(package_dir: Path = PACKAGE_DIR, model_dir: Path = MODEL_DIR) -> dict:
    """The identity of the code at ``package_dir`` with the models at ``model_dir``."""
    return {"versions": library_versions(),
            "source_sha256": files_sha256(package_dir, "*.py"),
            "model_sha256": files_sha256(model_dir, "*.xml"),
            "git_commit": git_commit(package_dir)}


def differences(recorded: dict | None, current: dict) -> list[str]:
    """What differs between a run's recorded code and ``current`` (``COMPARED`` keys only),
    as short phrases; a run without a record differs in everything."""
    if recorded is None:
        return ["the run has no record of its code"]
    found = []
    for key in COMPARED:
        if key == "versions":
            versions = recorded.get(key, {})
            found += [f"{name} {versions.get(name)} -> {version}"
                      for name, version in current[key].items() if versions.get(name) != version]
        elif recorded.get(key) != current[key]:
            found.append(f"{key} {str(recorded.get(key))[:12]} -> {current[key][:12]}")
    return found
