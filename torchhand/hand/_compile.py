"""Compile a robot-hand file with MuJoCo's own compiler: MJCF (``<include>``, ``<default>`` classes, ``meshdir``
and every other MJCF feature MuJoCo reads) and URDF.

:func:`compile_file` returns the compiled ``mujoco.MjModel``; every failure is one line naming the file, MuJoCo's
message included. A URDF file is compiled with these ``<compiler>`` settings added (a ``<mujoco>`` element the
file already has wins, setting by setting):

* ``meshdir`` the URDF's folder and ``strippath="false"``: mesh paths relative to the file, as URDF tools read them
  (``package://NAME/`` prefixes resolved against the file's folder and its parents);
* ``fusestatic="false"``: links on fixed joints stay bodies, so fingertip links keep their names and frames;
* ``discardvisual="true"``: only ``<collision>`` elements become geoms;
* ``balanceinertia="true"``: inertias that violate the triangle inequality (the dex-urdf Allegro's) are balanced as
  MuJoCo documents, instead of refused.

Unnamed ``<collision>`` elements are named ``<link>_collision<k>`` so that MuJoCo warns of no duplicate names.
"""

from __future__ import annotations

import re
import xml.etree.ElementTree as ET
from pathlib import Path

from ..errors import FileFormatError, MissingFileError

__all__ = ["compile_file", "is_urdf", "urdf_as_mujoco_xml"]

URDF_COMPILER = {"strippath": "false", "fusestatic": "false", "discardvisual": "true", "balanceinertia": "true"}
"""The ``<compiler>`` settings a URDF file is compiled with (module docstring), besides ``meshdir``."""


def is_urdf(path) -> bool:
    """Whether ``path`` is a URDF file: its root element is ``<robot>`` (the extension is not consulted)."""
    try:
        for _, elem in ET.iterparse(str(path), events=("start",)):
            return elem.tag == "robot"
    except (ET.ParseError, OSError):
        return False
    return False


def compile_file(path):
    """The ``mujoco.MjModel`` of an MJCF or URDF file. Raises MissingFileError (no such file, or a file it names
    missing) or FileFormatError (anything else MuJoCo refuses), MuJoCo's message on the same line."""
    import mujoco

    path = Path(path)
    if not path.is_file():
        raise MissingFileError(f"hand file not found: {path}")
    try:
        if is_urdf(path):
            return mujoco.MjModel.from_xml_string(urdf_as_mujoco_xml(path))
        return mujoco.MjModel.from_xml_path(str(path))
    except ValueError as err:
        msg = _one_line(err)
        kind = MissingFileError if re.search(r"Error opening file|No such file|resource not found", msg) else FileFormatError
        raise kind(f"{path}: MuJoCo cannot compile it: {msg}") from None


def urdf_as_mujoco_xml(path) -> str:
    """The URDF text of ``path`` with the ``<mujoco><compiler .../></mujoco>`` settings of the module docstring."""
    path = Path(path).resolve()
    try:
        root = ET.parse(path).getroot()
    except ET.ParseError as err:
        raise FileFormatError(f"{path}: malformed XML: {err}") from None
    ext = root.find("mujoco")
    if ext is None:
        ext = ET.SubElement(root, "mujoco")
    compiler = ext.find("compiler")
    if compiler is None:
        compiler = ET.SubElement(ext, "compiler")
    for key, value in {"meshdir": str(path.parent) + "/", **URDF_COMPILER}.items():
        compiler.attrib.setdefault(key, value)
    for link in root.iter("link"):
        for k, col in enumerate(link.findall("collision")):
            col.attrib.setdefault("name", f"{link.get('name', 'link')}_collision{k}")
    for mesh in root.iter("mesh"):
        if mesh.get("filename", "").startswith("package://"):
            mesh.set("filename", _package_path(path, mesh.get("filename")))
    return ET.tostring(root, encoding="unicode")


def _package_path(urdf: Path, uri: str) -> str:
    """A ``package://NAME/REST`` mesh path as a path that exists: REST below the URDF's folder or one of its parents
    (the package's root), else NAME/REST there. Raises MissingFileError when neither exists."""
    rest = uri[len("package://"):]
    name, _, tail = rest.partition("/")
    for base in (urdf.parent, *urdf.parent.parents):
        for cand in (base / tail, base / name / tail):
            if cand.is_file():
                return str(cand)
    raise MissingFileError(f"{urdf}: mesh {uri!r} not found below the file's folder or its parents")


def _one_line(err: Exception) -> str:
    return re.sub(r"\s+", " ", str(err)).strip()
