"""A thin ctypes binding to the Embree 4 library that the embreex wheel bundles.

embreex's ``TriangleMesh`` copies vertices and indices into Embree one element at a time in
Python, which cost more than building the BVH. Here the scene shares the caller's numpy arrays
(``rtcSetSharedGeometryBuffer``: no copy at all) and rays go to ``rtcIntersect8`` in packets
of 8 laid out in one aligned numpy array, one foreign call per packet; ctypes releases the GIL
during each call, so threads cast in parallel. Per ray, packets cast about 1.1x as long as
embreex's loop of single rays in C (3 M ngi-aerial rays, one thread), which a call per ray from
Python could not match; building the scene costs well under half of embreex's. Nothing of
embreex is imported: only its shared library is loaded.
"""

from __future__ import annotations

import ctypes
import glob
import importlib.util
import os
import threading

import numpy as np

from orthomvp.errors import InputError

LANES = 8
"""Rays per packet (``RTCRayHit8``: on ngi-aerial rays about 10% faster than packets of 16)."""

ROWS = 32
"""Rows of LANES lanes (4 bytes each) reserved per packet: the 12 ray rows, the 7 hit rows and
the instance ids, which Embree's build configuration sizes (one level, with or without instance
primitive ids: 21 rows); the rest is padding, so that no configuration writes past a packet."""

# Row of each RTCRayHit8 member (struct of arrays, one lane per ray of the packet).
ORG, TNEAR, DIR, TIME, TFAR, MASK, ID, FLAGS = 0, 3, 4, 7, 8, 9, 10, 11
NG, U, V, PRIM, GEOM, INST = 12, 15, 16, 17, 18, 19

INVALID = 0xFFFFFFFF
"""RTC_INVALID_GEOMETRY_ID."""

_GEOMETRY_TRIANGLE = 0
_BUFFER_INDEX, _BUFFER_VERTEX = 0, 1
_FORMAT_UINT3, _FORMAT_FLOAT3 = 0x5003, 0x9003
_SCENE_FLAG_ROBUST = 1 << 2
_ERRORS = {
    1: "unknown error",
    2: "invalid argument",
    3: "invalid operation",
    4: "out of memory",
    5: "unsupported CPU",
    6: "cancelled",
}

_lock = threading.Lock()
_state: dict[str, object] = {}


def library_path() -> str:
    """The Embree 4 shared library of the installed embreex wheel (``embreex.libs`` on Linux
    and Windows, ``embreex/.dylibs`` on macOS), found without importing embreex."""
    spec = importlib.util.find_spec("embreex")
    if spec is None or not spec.submodule_search_locations:
        raise InputError(
            "Embree ray casting needs the package embreex (its bundled Embree 4 library): "
            "install it with 'pip install embreex'"
        )
    package = list(spec.submodule_search_locations)[0]
    site = os.path.dirname(package)
    for pattern in ("embreex.libs/*embree4*", "embreex/.dylibs/*embree4*", "embreex/*embree4*"):
        found = sorted(glob.glob(os.path.join(site, pattern)))
        if found:
            return found[0]
    raise InputError(f"no Embree 4 library found beside embreex in {site}")


def _library() -> tuple[ctypes.CDLL, int]:
    """The loaded library and the process's one Embree device, made on first use."""
    with _lock:
        if "lib" not in _state:
            lib = ctypes.CDLL(library_path())
            vp, u, sz = ctypes.c_void_p, ctypes.c_uint, ctypes.c_size_t
            signatures = {
                "rtcNewDevice": ([ctypes.c_char_p], vp),
                "rtcGetDeviceError": ([vp], ctypes.c_int),
                "rtcNewScene": ([vp], vp),
                "rtcSetSceneFlags": ([vp, ctypes.c_int], None),
                "rtcNewGeometry": ([vp, ctypes.c_int], vp),
                "rtcSetSharedGeometryBuffer": (
                    [vp, ctypes.c_int, u, ctypes.c_int, vp, sz, sz, sz],
                    None,
                ),
                "rtcCommitGeometry": ([vp], None),
                "rtcAttachGeometry": ([vp, vp], u),
                "rtcReleaseGeometry": ([vp], None),
                "rtcCommitScene": ([vp], None),
                "rtcReleaseScene": ([vp], None),
                "rtcIntersect8": ([vp, vp, vp, vp], None),
            }
            for name, (args, res) in signatures.items():
                fn = getattr(lib, name)
                fn.argtypes, fn.restype = args, res
            device = lib.rtcNewDevice(None)
            if not device:
                raise InputError("Embree could not create a device (unsupported CPU?)")
            _state["lib"], _state["device"] = lib, device
        return _state["lib"], _state["device"]  # type: ignore[return-value]


def _aligned(shape: tuple[int, ...], dtype: type, align: int = 64) -> np.ndarray:
    """A zeroed array of ``shape`` whose data starts on an ``align``-byte boundary."""
    size = int(np.prod(shape)) * np.dtype(dtype).itemsize
    raw = np.zeros(size + align, np.uint8)
    start = -raw.ctypes.data % align
    return raw[start : start + size].view(dtype).reshape(shape)


class Scene:
    """A committed Embree scene of one triangle mesh, sharing the caller's buffers.

    ``vertices`` (n, 3) float32 and ``faces`` (m, 3) int32 or uint32 (indices into the
    vertices); both are kept (by reference when already C-contiguous of those types) for the
    scene's lifetime. Embree reads 16 bytes at the last vertex, so the vertex array is copied
    once into a buffer with 4 bytes of padding unless it already is a view of one (see
    :func:`vertex_buffer`). The BVH is built here (robust mode, as embreex's default scene).
    """

    def __init__(self, vertices: np.ndarray, faces: np.ndarray):
        self._lib, device = _library()
        lib = self._lib
        self._vertices = _padded(vertices)
        self._faces = np.ascontiguousarray(faces).view(np.uint32)
        if self._faces.dtype.itemsize != 4 or self._faces.shape[-1:] != (3,):
            raise InputError("Embree faces must be (m, 3) 32-bit indices")
        self._scene = lib.rtcNewScene(device)
        lib.rtcSetSceneFlags(self._scene, _SCENE_FLAG_ROBUST)
        geom = lib.rtcNewGeometry(device, _GEOMETRY_TRIANGLE)
        lib.rtcSetSharedGeometryBuffer(
            geom, _BUFFER_VERTEX, 0, _FORMAT_FLOAT3, self._vertices.ctypes.data, 0, 12,
            len(self._vertices),
        )  # fmt: skip
        lib.rtcSetSharedGeometryBuffer(
            geom, _BUFFER_INDEX, 0, _FORMAT_UINT3, self._faces.ctypes.data, 0, 12,
            len(self._faces),
        )  # fmt: skip
        lib.rtcCommitGeometry(geom)
        lib.rtcAttachGeometry(self._scene, geom)
        lib.rtcReleaseGeometry(geom)
        lib.rtcCommitScene(self._scene)
        _check(lib, device, "building the scene")
        self._all = _aligned((LANES,), np.int32)
        self._all[:] = -1

    def __del__(self) -> None:
        scene = getattr(self, "_scene", None)
        if scene:
            self._lib.rtcReleaseScene(scene)
            self._scene = None

    def intersect(
        self, origins: np.ndarray, directions: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """First hits of rays ``origins`` + t ``directions`` (n, 3) float32, t in [0, inf):
        (t, triangle, u, v) with t float32 in units of the direction's length (inf on a
        miss), triangle int32 (-1 on a miss), barycentric u, v float32."""
        n = len(origins)
        packets = max(-(-n // LANES), 1)
        buf = _aligned((packets, ROWS, LANES), np.float32)
        ints = buf.view(np.uint32)
        full, rest = divmod(n, LANES)
        for row, xyz in ((ORG, origins), (DIR, directions)):
            buf[:full, row : row + 3] = (
                xyz[: full * LANES].reshape(full, LANES, 3).transpose(0, 2, 1)
            )
            buf[full:, row : row + 3, :rest] = xyz[full * LANES :].T
        buf[:, TFAR] = np.inf
        ints[:, MASK] = INVALID
        ints[:, PRIM : INST + 1] = INVALID
        last = _aligned((LANES,), np.int32)
        last[: n - (packets - 1) * LANES] = -1
        fn, scene, valid = self._lib.rtcIntersect8, self._scene, self._all.ctypes.data
        base, step = buf.ctypes.data, buf[0].nbytes
        for k in range(packets - 1):
            fn(valid, scene, base + k * step, None)
        fn(last.ctypes.data, scene, base + (packets - 1) * step, None)
        tri = ints[:, PRIM].ravel()[:n].view(np.int32)
        return buf[:, TFAR].ravel()[:n], tri, buf[:, U].ravel()[:n], buf[:, V].ravel()[:n]


def vertex_buffer(n: int) -> np.ndarray:
    """An (n, 3) float32 array with the 4 bytes of padding after it that Embree needs for a
    shared vertex buffer (fill it, then pass it to :class:`Scene` without a copy)."""
    return np.empty(3 * n + 1, np.float32)[: 3 * n].reshape(n, 3)


def _padded(vertices: np.ndarray) -> np.ndarray:
    """``vertices`` if it is a C-contiguous float32 (n, 3) view of :func:`vertex_buffer`, else
    a padded copy."""
    v = vertices
    base = v.base
    if (
        v.dtype == np.float32
        and v.ndim == 2
        and v.shape[1] == 3
        and v.flags.c_contiguous
        and isinstance(base, np.ndarray)
        and base.ctypes.data <= v.ctypes.data
        and v.ctypes.data + v.nbytes + 4 <= base.ctypes.data + base.nbytes
    ):
        return v
    out = vertex_buffer(len(v))
    out[:] = v
    return out


def _check(lib: ctypes.CDLL, device: int, what: str) -> None:
    code = lib.rtcGetDeviceError(device)
    if code:
        raise InputError(f"Embree failed {what}: {_ERRORS.get(code, f'error {code}')}")
