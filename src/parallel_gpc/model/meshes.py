"""Mesh files named by a robot's model file: which file each one means, if any allowed one.

A mesh is never needed for the dynamics; it only dresses the view. A model file names a mesh by
a URI, resolved here among the *allowed roots* only (the model file's folder, then the package
path) and never anywhere else:

* a relative path or ``file://relative``: in the model file's folder (an MJCF
  ``<compiler meshdir=…>`` is taken relative to it);
* an absolute path or ``file:///abs``: only if it lies inside an allowed root;
* ``package://NAME/rest``: ``R/NAME/rest`` for each allowed root R in order, or ``R/rest`` when
  R itself is the folder named NAME (a ROS package given directly); ``package:///rest`` (an
  empty package name, as in the Gepetto collection) is ``R/rest``;
* any other scheme (``http://``, ``model://``, …) does not resolve.

A candidate resolves when it is a regular file whose real path (symlinks followed) lies inside
its root: no ``..`` or symlink escapes. Nothing here opens a mesh; the view reads only resolved
files. The package path is the ``package_path`` argument, then the folders of
:data:`PACKAGE_PATH_ENV`, then those of ``ROS_PACKAGE_PATH`` (the ROS convention; folders that
do not exist are skipped there), each list separated by :data:`os.pathsep`.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import RobotFormatError

#: Environment variable listing package folders (``os.pathsep``-separated), searched after the
#: ``package_path`` argument and before ``ROS_PACKAGE_PATH``.
PACKAGE_PATH_ENV = "PARALLEL_GPC_PACKAGE_PATH"
#: The ROS variable, the last fallback.
ROS_PACKAGE_PATH_ENV = "ROS_PACKAGE_PATH"


def _folder(entry, what: str) -> Path:
    if isinstance(entry, bool) or not isinstance(entry, (str, os.PathLike)) or not str(entry).strip():
        raise RobotFormatError(f"{what} entry {entry!r} must be a folder path (str or os.PathLike)")
    path = Path(entry).expanduser()
    if not path.is_dir():
        raise RobotFormatError(f"{what} entry {str(entry)!r} is not an existing folder; give the folder that "
                               "holds the mesh packages")
    return path.resolve()


def package_roots(package_path=None, environ=None) -> tuple[Path, ...]:
    """The package folders searched for ``package://`` meshes, in order (resolved, no duplicates).

    Args:
        package_path: a folder (str or os.PathLike), an ``os.pathsep``-separated string of
            folders, or a list of folders; None: none.
        environ: the environment (default ``os.environ``).

    Raises:
        RobotFormatError: an entry of ``package_path`` or of :data:`PACKAGE_PATH_ENV` is not an
            existing folder.
    """
    environ = os.environ if environ is None else environ
    if package_path is None:
        given = []
    elif isinstance(package_path, (str, os.PathLike)):
        given = [p for p in str(package_path).split(os.pathsep) if p] or [package_path]
    elif isinstance(package_path, (list, tuple)):
        given = list(package_path)
    else:
        raise RobotFormatError(f"package_path = {package_path!r} ({type(package_path).__name__}) must be a "
                               "folder, an os.pathsep-separated string of folders or a list of folders")
    roots = [_folder(p, "package_path") for p in given]
    roots += [_folder(p, PACKAGE_PATH_ENV) for p in environ.get(PACKAGE_PATH_ENV, "").split(os.pathsep) if p]
    roots += [Path(p).resolve() for p in environ.get(ROS_PACKAGE_PATH_ENV, "").split(os.pathsep)
              if p and Path(p).is_dir()]
    return tuple(dict.fromkeys(roots))


def _inside(candidate: Path, root: Path) -> Path | None:
    """The real path of ``candidate`` if it is a regular file inside ``root`` (resolved), else None."""
    try:
        real = candidate.resolve()
        return real if real.is_relative_to(root) and real.is_file() else None
    except (OSError, ValueError, RuntimeError):  # NUL bytes, symlink loops, permissions
        return None


def resolve_mesh(uri: str, folder: Path, roots: tuple[Path, ...], base: Path | None = None) -> Path | None:
    """The file a mesh URI means among the allowed roots (module docstring), or None.

    Args:
        uri: the mesh reference as written in the model file.
        folder: the model file's folder (the first allowed root).
        roots: the package folders (:func:`package_roots`).
        base: folder of relative paths (default ``folder``; an MJCF ``meshdir``), itself
            confined to ``folder``.
    """
    folder = folder.resolve()
    allowed = (folder, *(r for r in roots if r != folder))
    if uri.startswith("package://"):
        rest = uri[len("package://"):]
        name, sub = ("", rest.lstrip("/")) if rest.startswith("/") else (rest.partition("/")[0], rest.partition("/")[2])
        if not sub:
            return None
        for root in allowed:
            candidates = [root / name / sub] if name else [root / sub]
            if name and root.name == name:
                candidates.append(root / sub)
            for candidate in candidates:
                found = _inside(candidate, root)
                if found is not None:
                    return found
        return None
    local = uri[len("file://"):] if uri.startswith("file://") else uri
    if not local or "://" in local:
        return None
    path = Path(local)
    if path.is_absolute():
        for root in allowed:
            found = _inside(path, root)
            if found is not None:
                return found
        return None
    return _inside((base if base is not None else folder) / path, folder)


def mesh_uris(root, model_format: str) -> tuple[tuple[str, Path | None], ...]:
    """(uri, base folder of relative paths or None) of every mesh a parsed model file names.

    Args:
        root: the XML root element (``<robot>`` or ``<mujoco>``).
        model_format: ``"urdf"`` or ``"mjcf"``.
    """
    if model_format == "urdf":
        return tuple((m.get("filename", ""), None) for m in root.iter("mesh"))
    compiler = root.find("compiler")
    meshdir = None if compiler is None else (compiler.get("meshdir") or compiler.get("assetdir"))
    return tuple((m.get("file"), Path(meshdir) if meshdir else None) for m in root.iter("mesh") if m.get("file"))


def resolve_meshes(root, model_format: str, model_path: Path, roots: tuple[Path, ...]):
    """Resolve every mesh of a parsed model file.

    Returns:
        (resolved, unresolved, references): a dict URI → real file path of the meshes that
        resolve, the tuple of URIs that do not (each once, in file order), and the URI of every
        mesh reference in file order (a URI named by several links is there once per link).
    """
    folder = Path(model_path).resolve().parent
    resolved, unresolved = {}, []
    uris = mesh_uris(root, model_format)
    for uri, meshdir in uris:
        if uri in resolved or uri in unresolved:
            continue
        base = None if meshdir is None else folder / meshdir
        found = resolve_mesh(uri, folder, roots, base)
        if found is None:
            unresolved.append(uri)
        else:
            resolved[uri] = found
    return resolved, tuple(unresolved), tuple(uri for uri, _ in uris)

