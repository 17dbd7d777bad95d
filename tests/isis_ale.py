"""Spiceinit'd test cubes from ALE's public test data (tests/data/isis/<instrument>/, see its
README): a real ISIS label (its IsisCube groups and the NaifKeywords spiceinit wrote) with the
four SPICE tables written, as spiceinit stores them, from the positions and rotations of ALE's
ISD of the same image; and the comparison of the camera read from such a cube with the camera
of ALE's ISD (both through orthomvp.camera.csm)."""

from __future__ import annotations

import gzip
import json
import re
from collections.abc import Callable
from pathlib import Path

import numpy as np

from orthomvp.camera.csm.isd import camera_from_isd
from orthomvp.camera.isis import read_cube_camera

DATA = Path(__file__).parent / "data" / "isis"
_LABEL_BYTES = 1 << 18  # room left for the label before the tables' bytes


def ale_isd(instrument: str, name: str) -> dict:
    """ALE's ISD ``name`` (gzipped JSON) of ``instrument``'s test image."""
    return json.loads(gzip.decompress((DATA / instrument / name).read_bytes()))


def real_cube(path: Path, instrument: str, name: str, edit: Callable[[str], str]) -> Path:
    """Write at ``path`` ALE's spiceinit'd cube ``name`` (gzipped) of ``instrument`` with its
    label text ``edit``-ed (padded back to the bytes the label reserves)."""
    data = bytearray(gzip.decompress((DATA / instrument / name).read_bytes()))
    end = data.index(b"\nEnd\n") + 5
    reserved = _reserved(data)
    text = edit(data[:end].decode("latin-1")).encode("latin-1")
    assert len(text) <= reserved
    data[:reserved] = text + bytes(reserved - len(text))
    path.write_bytes(bytes(data))
    return path


def _reserved(data: bytes) -> int:
    """The label's reserved bytes (``Object = Label`` ``Bytes``)."""
    match = re.search(rb"Object = Label\n\s*Bytes\s*=\s*(\d+)", data)
    assert match is not None
    return int(match[1])


def block(text: str, kind: str, name: str | None = None) -> str:
    """The first top-level ``Object = kind`` block of label ``text`` (named ``name``)."""
    for match in re.finditer(
        rf"^Object = {kind}\n(?:(?!^End_Object$).*\n)*?^End_Object\n", text, re.MULTILINE
    ):
        if name is None or re.search(rf"^  Name\s+= \"?{re.escape(name)}\"?\n", match[0], re.M):
            return match[0]
    raise KeyError(f"no Object = {kind} {name or ''}")


def _pvl(value: object) -> str:
    if isinstance(value, bool):
        return "TRUE" if value else "FALSE"
    if isinstance(value, list | tuple):
        return "(" + ", ".join(_pvl(v) for v in value) + ")"
    if isinstance(value, str):
        return value if re.fullmatch(r"[A-Za-z0-9_./:+-]+", value) else f'"{value}"'
    return repr(value)


def _table(name: str, keywords: dict, columns: dict[str, np.ndarray], start: int) -> str:
    fields = "".join(
        f"\n  Group = Field\n    Name = {key}\n    Type = {_type(values)}\n    Size = 1\n"
        "  End_Group\n"
        for key, values in columns.items()
    )
    records = len(next(iter(columns.values())))
    head = "".join(f"  {k} = {_pvl(v)}\n" for k, v in keywords.items())
    return (
        f"Object = Table\n  Name = {name}\n  StartByte = {start}\n"
        f"  Bytes = {len(_records(columns))}\n  Records = {records}\n  ByteOrder = Lsb\n"
        f"{head}{fields}End_Object\n\n"
    )


def _type(values: np.ndarray) -> str:
    """ISIS's field type of a column: Integer (32 bits) for integers, else Double."""
    return "Integer" if np.asarray(values).dtype.kind == "i" else "Double"


def _records(columns: dict[str, np.ndarray]) -> bytes:
    """The table's bytes: its records, little-endian, fields in order."""
    dtype = [(k, "<i4" if _type(v) == "Integer" else "<f8") for k, v in columns.items()]
    rows = np.zeros(len(next(iter(columns.values()))), dtype)
    for key, values in columns.items():
        rows[key] = values
    return rows.tobytes()


def _spice_tables(isd: dict) -> list[tuple[str, dict, dict[str, np.ndarray]]]:
    """The four SPICE tables as spiceinit writes them, from the ISD's states."""
    out = []
    rotations = (("InstrumentPointing", "instrument_pointing"), ("BodyRotation", "body_rotation"))
    for name, key in rotations:
        part = isd[key]
        q = np.asarray(part["quaternions"], dtype=float)
        columns = {f"J2000Q{i}": q[:, i] for i in range(4)}
        if "angular_velocities" in part:
            av = np.asarray(part["angular_velocities"], dtype=float)
            columns |= {f"AV{i + 1}": av[:, i] for i in range(3)}
        columns["ET"] = np.asarray(part["ephemeris_times"], dtype=float)
        keywords = {"TimeDependentFrames": part["time_dependent_frames"]}
        if "constant_rotation" in part:
            keywords["ConstantFrames"] = part["constant_frames"]
            keywords["ConstantRotation"] = part["constant_rotation"]
        out.append((name, keywords, columns))
    positions = (("InstrumentPosition", "instrument_position"), ("SunPosition", "sun_position"))
    for name, key in positions:
        part = isd[key]
        p = np.asarray(part["positions"], dtype=float)
        columns = {f"J2000{a}": p[:, i] for i, a in enumerate("XYZ")}
        if "velocities" in part:
            v = np.asarray(part["velocities"], dtype=float)
            columns |= {f"J2000{a}V": v[:, i] for i, a in enumerate("XYZ")}
        columns["ET"] = np.asarray(part["ephemeris_times"], dtype=float)
        out.append((name, {}, columns))
    return out


def spice_cube(
    path: Path,
    label: str,
    isd: dict,
    *,
    edit: Callable[[str], str] = lambda text: text,
    tables: tuple[tuple[str, dict, dict[str, np.ndarray]], ...] = (),
) -> Path:
    """Write at ``path`` a cube of ``label``'s IsisCube object (``edit``-ed) and NaifKeywords,
    with the SPICE tables of ``isd`` and any further ``tables`` (name, keywords, columns) after
    the label, as a spiceinit'd cube holds them (no pixels: the camera needs none)."""
    text = edit(block(label, "IsisCube"))
    body = bytearray()
    objects = ""
    for name, keywords, columns in (*_spice_tables(isd), *tables):
        objects += _table(name, keywords, columns, _LABEL_BYTES + len(body) + 1)
        body += _records(columns)
    head = (text + "\n" + objects + block(label, "NaifKeywords") + "End\n").encode("latin-1")
    assert len(head) <= _LABEL_BYTES
    path.write_bytes(head + bytes(_LABEL_BYTES - len(head)) + bytes(body))
    return path


def pixel_differences(
    cube: Path,
    isd: dict,
    height: float = 0.0,
    *,
    samples: tuple[float, float] | None = None,
    lines: tuple[float, float] | None = None,
    n: int = 9,
) -> np.ndarray:
    """|pixel| differences (px) between the camera read from ``cube`` and the camera of ALE's
    ``isd`` over an n x n grid of ``samples`` x ``lines`` (default the image): at the ground
    points (at ``height``) of ALE's camera, the two cameras' projections (u, v); and the
    distance between the two cameras' ground points of the grid in ground pixels (the distance
    to the next sample's), as a third column."""
    ours, theirs = read_cube_camera(cube), camera_from_isd(isd)
    samples = samples or (0.0, isd["image_samples"] - 1.0)
    lines = lines or (0.0, isd["image_lines"] - 1.0)
    u, v = np.meshgrid(np.linspace(*samples, n), np.linspace(*lines, n))
    uv = np.stack([u.ravel(), v.ravel()], -1)
    ground = theirs.image_to_ground(uv, height)
    projected = np.abs(ours.project(ground)[0] - theirs.project(ground)[0])
    step = np.linalg.norm(theirs.image_to_ground(uv + [1.0, 0.0], height) - ground, axis=1)
    apart = np.linalg.norm(ours.image_to_ground(uv, height) - ground, axis=1) / step
    return np.column_stack([projected, apart])
