"""Mesh file names of a URDF resolved as ROS resolves them.

``package://NAME/rest`` is ``<share directory of NAME>/rest``: the ament index when
``ament_index_python`` is there, then ``<prefix>/share/NAME`` for every prefix of
``AMENT_PREFIX_PATH``, then the prefixes the pip wheels install to (``cmeel.prefix`` of
example-robot-data, Pinocchio and Coal, on ``sys.path``), then the caller's
``package_dirs``. ``file://`` and plain paths are taken as they are, relative ones from the
URDF's directory.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Sequence
from pathlib import Path

from tocontrol_ros.core.errors import ModelError

__all__ = ["resolve_uri", "share_directories"]


def share_directories(package: str, package_dirs: Sequence[str | os.PathLike] = ()
                      ) -> list[Path]:
    """Candidate share directories of ``package``, in the order they are tried.

    Parameters
    ----------
    package : str
        A ROS package name (``example-robot-data``).
    package_dirs : sequence of path
        Extra directories: each is either a package's share directory itself (its name is
        ``package``) or a directory holding one per package.
    """
    found: list[Path] = []
    try:
        from ament_index_python.packages import (
            PackageNotFoundError,
            get_package_share_directory,
        )
        try:
            found.append(Path(get_package_share_directory(package)))
        except (PackageNotFoundError, ValueError, LookupError, OSError):
            pass
    except ImportError:  # a core without ROS: the prefixes below
        pass
    for prefix in os.environ.get("AMENT_PREFIX_PATH", "").split(os.pathsep):
        if prefix:
            found.append(Path(prefix) / "share" / package)
    for entry in sys.path:
        found.append(Path(entry or ".") / "cmeel.prefix" / "share" / package)
    for extra in package_dirs:
        extra = Path(extra)
        found.append(extra if extra.name == package else extra / package)
    return found


def resolve_uri(uri: str, base_dir: Path | None = None,
                package_dirs: Sequence[str | os.PathLike] = ()) -> Path:
    """The file a URDF names by ``uri`` (see the module).

    Parameters
    ----------
    uri : str
        ``package://pkg/path``, ``file:///abs/path`` or a path.
    base_dir : Path, optional
        The URDF's directory, for relative paths (default: the working directory).
    package_dirs : sequence of path
        See :func:`share_directories`.

    Raises
    ------
    ModelError
        The file cannot be found: the message names the URI and where it was looked for.
    """
    if uri.startswith("package://"):
        rest = uri[len("package://"):]
        package, _, relative = rest.partition("/")
        if not package or not relative:
            raise ModelError(f"mesh {uri!r}: a package URI is package://NAME/PATH")
        tried = share_directories(package, package_dirs)
        for share in tried:
            path = share / relative
            if path.is_file():
                return path
        places = ", ".join(str(p) for p in dict.fromkeys(tried) if p.parent.is_dir()) or \
            "no share directory of that package"
        raise ModelError(f"mesh file {uri!r} not found: package {package!r} resolved to "
                         f"{places} (set AMENT_PREFIX_PATH or pass `package_dirs`)")
    path = Path(uri[len("file://"):] if uri.startswith("file://") else uri)
    if not path.is_absolute():
        path = (base_dir or Path.cwd()) / path
    if not path.is_file():
        raise ModelError(f"mesh file {uri!r} not found (looked at {path})")
    return path
