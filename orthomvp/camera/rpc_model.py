"""RPC00B rational polynomial coefficients: parsing, checking and evaluating the polynomials.

An :class:`Rpc` maps WGS84 geodetic longitude and latitude (degrees) and ellipsoidal height
(metres) to pixels with the RPC00B polynomials, in the 20-term order of the GeoTIFF RPC
extension, NITF RPC00B and GDAL: with L, P, H the normalised longitude, latitude and height,
1, L, P, H, LP, LH, PH, L^2, P^2, H^2, PLH, L^3, LP^2, LH^2, L^2P, P^3, PH^2, L^2H, P^2H, H^3.
sample = samp_off + samp_scale * SAMP_NUM / SAMP_DEN, line likewise; (sample, line) has the first
pixel's centre at (0, 0). :mod:`orthomvp.camera.rpc` binds one to a world frame as a camera.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np

from orthomvp.camera.model import FieldError

OFFSETS_SCALES = (
    "line_off",
    "samp_off",
    "lat_off",
    "long_off",
    "height_off",
    "line_scale",
    "samp_scale",
    "lat_scale",
    "long_scale",
    "height_scale",
)
"""The RPC's scalar parameters, named as in GDAL's RPC metadata (lower case) and Orthority."""
COEFFICIENTS = ("line_num_coeff", "line_den_coeff", "samp_num_coeff", "samp_den_coeff")
"""The RPC's four 20-coefficient polynomials, in that order."""
RPC_KEYS = OFFSETS_SCALES + COEFFICIENTS
"""Every key an :class:`Rpc` needs."""

GEODETIC = 4979
"""The RPCs' own coordinates, an EPSG code: WGS84 longitude, latitude (degrees), ellipsoidal
height (m)."""

_CHUNK = 1 << 16  # points per polynomial evaluation (bounds the (n, 20) term matrices)
_TOLERANCE = 1e-10  # image to ground: last Newton step, normalised lon/lat units
_ITERATIONS = 30  # image to ground: most Newton steps before a point is given up (NaN)


def _poly(c: np.ndarray, lon: np.ndarray, lat: np.ndarray, h: np.ndarray) -> np.ndarray:
    """The RPC00B polynomial with coefficients ``c`` (20,) at normalised (L, P, H), in Horner
    form."""
    out = c[0] + lon * (
        c[1]
        + lat * (c[4] + h * c[10])
        + h * c[5]
        + lon * (c[7] + lon * c[11] + lat * c[14] + h * c[17])
    )
    out += lat * (c[2] + h * c[6] + lat * (c[8] + lon * c[12] + lat * c[15] + h * c[18]))
    out += h * (c[3] + h * (c[9] + lon * c[13] + lat * c[16] + h * c[19]))
    return out


def _poly_gradient(
    c: np.ndarray, lon: np.ndarray, lat: np.ndarray, h: np.ndarray
) -> tuple[np.ndarray, np.ndarray]:
    """The derivatives of :func:`_poly` by L and by P."""
    d_lon = (
        c[1]
        + lat * (c[4] + h * c[10] + lat * c[12] + 2 * lon * c[14])
        + h * (c[5] + h * c[13] + 2 * lon * c[17])
        + lon * (2 * c[7] + 3 * lon * c[11])
    )
    d_lat = (
        c[2]
        + lon * (c[4] + h * c[10] + 2 * lat * c[12] + lon * c[14])
        + h * (c[6] + h * c[16] + 2 * lat * c[18])
        + lat * (2 * c[8] + 3 * lat * c[15])
    )
    return d_lon, d_lat


def finite_number(key: str, value: object) -> float:
    """``value`` as a finite float; FieldError naming ``key`` otherwise."""
    if isinstance(value, bool | str | bytes):
        raise FieldError(key, f"{key} must be a number, got {value!r}")
    try:
        number = float(value)  # type: ignore[arg-type]
    except (TypeError, ValueError):
        raise FieldError(key, f"{key} must be a number, got {value!r}") from None
    if not np.isfinite(number):
        raise FieldError(key, f"{key} must be finite, got {value!r}")
    return number


def _coefficients(key: str, value: object) -> np.ndarray:
    """``value`` as a read-only (20,) float64 array; FieldError naming ``key`` otherwise."""
    items = list(value) if isinstance(value, list | tuple | np.ndarray) else None
    if items is None or len(items) != 20:
        got = f"{len(items)}" if items is not None else repr(value)
        raise FieldError(key, f"{key} must be 20 coefficients, got {got}")
    arr = np.array([finite_number(f"{key}[{i}]", v) for i, v in enumerate(items)], dtype=np.float64)
    arr.setflags(write=False)
    return arr


@dataclass(frozen=True, eq=False)
class Rpc:
    """RPC00B rational polynomial coefficients (see the module docstring).

    Offsets and scales: ``line_off``, ``samp_off``, ``line_scale``, ``samp_scale`` in pixels;
    ``lat_off``, ``long_off``, ``lat_scale``, ``long_scale`` in degrees; ``height_off``,
    ``height_scale`` in metres (ellipsoidal). The four polynomials (20,) each. Construction
    raises FieldError (an InputError naming the key) for a missing, non-numeric or non-finite
    value, a zero scale, a wrong number of coefficients or a denominator with all zeros.
    """

    line_off: float
    samp_off: float
    lat_off: float
    long_off: float
    height_off: float
    line_scale: float
    samp_scale: float
    lat_scale: float
    long_scale: float
    height_scale: float
    line_num_coeff: np.ndarray
    line_den_coeff: np.ndarray
    samp_num_coeff: np.ndarray
    samp_den_coeff: np.ndarray

    def __post_init__(self) -> None:
        for key in OFFSETS_SCALES:
            value = finite_number(key, getattr(self, key))
            if key.endswith("_scale") and value == 0:
                raise FieldError(key, f"{key} must not be 0")
            object.__setattr__(self, key, value)
        for key in COEFFICIENTS:
            value = _coefficients(key, getattr(self, key))
            if key.endswith("_den_coeff") and not value.any():
                raise FieldError(key, f"{key} is all zeros (division by zero)")
            object.__setattr__(self, key, value)

    @classmethod
    def from_mapping(cls, values: Mapping[str, object]) -> Rpc:
        """The RPC of a mapping with the keys :data:`RPC_KEYS` (any case; others ignored), such
        as rasterio's ``RPC.to_dict()`` or Orthority's ``rpc``; FieldError for a missing key."""
        lower = {str(k).lower(): v for k, v in values.items()}
        missing = [key for key in RPC_KEYS if key not in lower]
        if missing:
            raise FieldError(missing[0], f"missing {', '.join(missing)}")
        return cls(**{key: lower[key] for key in RPC_KEYS})

    def to_dict(self) -> dict[str, float | list[float]]:
        """The parameters by their :data:`RPC_KEYS` (floats, lists of 20 floats)."""
        out: dict[str, float | list[float]] = {k: getattr(self, k) for k in OFFSETS_SCALES}
        out.update({k: getattr(self, k).tolist() for k in COEFFICIENTS})
        return out

    def normalise(
        self, lon: np.ndarray, lat: np.ndarray, height: np.ndarray
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Normalised (L, P, H) of degrees and metres."""
        return (
            (np.asarray(lon, np.float64) - self.long_off) / self.long_scale,
            (np.asarray(lat, np.float64) - self.lat_off) / self.lat_scale,
            (np.asarray(height, np.float64) - self.height_off) / self.height_scale,
        )

    def _ratios(
        self, lon: np.ndarray, lat: np.ndarray, h: np.ndarray, jacobian: bool = False
    ) -> tuple[np.ndarray, np.ndarray | None]:
        """Normalised (sample, line) (n, 2) of normalised (L, P, H) (n,), and with ``jacobian``
        their derivatives (n, 2, 2) by (L, P)."""
        n = lon.shape[0]
        out = np.empty((n, 2))
        jac = np.empty((n, 2, 2)) if jacobian else None
        pairs = (
            (self.samp_num_coeff, self.samp_den_coeff),
            (self.line_num_coeff, self.line_den_coeff),
        )
        for s in range(0, n, _CHUNK):
            part = slice(s, s + _CHUNK)
            args = lon[part], lat[part], h[part]
            for i, (num_c, den_c) in enumerate(pairs):
                num, den = _poly(num_c, *args), _poly(den_c, *args)
                with np.errstate(divide="ignore", invalid="ignore"):
                    out[part, i] = num / den
                    if jac is not None:
                        for k, (d_num, d_den) in enumerate(
                            zip(
                                _poly_gradient(num_c, *args),
                                _poly_gradient(den_c, *args),
                                strict=True,
                            )
                        ):
                            jac[part, i, k] = (d_num * den - num * d_den) / (den * den)
        return out, jac

    def project(self, lon: np.ndarray, lat: np.ndarray, height: np.ndarray) -> np.ndarray:
        """Pixels (..., 2), (u, v) = (sample, line), of WGS84 ``lon``, ``lat`` (degrees) and
        ellipsoidal ``height`` (metres), broadcast together; no domain check."""
        lon, lat, height = np.broadcast_arrays(*self.normalise(lon, lat, height))
        shape = lon.shape
        ratios, _ = self._ratios(lon.ravel(), lat.ravel(), height.ravel())
        scale = np.array([self.samp_scale, self.line_scale])
        offset = np.array([self.samp_off, self.line_off])
        return (ratios * scale + offset).reshape(shape + (2,))

    def ground(
        self,
        uv: np.ndarray,
        height: np.ndarray,
        *,
        start: tuple[np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray]:
        """WGS84 (lon, lat), degrees, imaged at pixels ``uv`` (..., 2) at ellipsoidal ``height``
        (metres, broadcast to ``uv[..., 0]``): Newton's method on (L, P) with the analytic
        Jacobian, vectorised, from ``start`` (lon, lat degrees; default the RPC's offsets)
        until a step is below 1e-10 normalised units (about 1e-11 degrees; the error after
        it, Newton converging quadratically, is far smaller). NaN where it does not converge
        within 30 steps, or where ``uv`` or ``height`` is not finite. No domain check."""
        uv = np.asarray(uv, np.float64)
        u, v, height = np.broadcast_arrays(uv[..., 0], uv[..., 1], np.asarray(height, np.float64))
        shape = u.shape
        target = np.stack(
            [
                (u.ravel() - self.samp_off) / self.samp_scale,
                (v.ravel() - self.line_off) / self.line_scale,
            ],
            axis=-1,
        )
        h = (height.ravel() - self.height_off) / self.height_scale
        x = np.zeros((h.size, 2))
        if start is not None:
            lon0, lat0, _ = self.normalise(start[0], start[1], 0.0)
            x[:, 0], x[:, 1] = (
                np.broadcast_to(lon0, shape).ravel(),
                np.broadcast_to(lat0, shape).ravel(),
            )
        active = np.flatnonzero(
            np.isfinite(target).all(axis=-1) & np.isfinite(h) & np.isfinite(x).all(axis=-1)
        )
        done = np.zeros(h.size, bool)
        for _ in range(_ITERATIONS):
            if not active.size:
                break
            xa = x[active]
            ratios, jac = self._ratios(xa[:, 0], xa[:, 1], h[active], jacobian=True)
            assert jac is not None
            residual = ratios - target[active]
            det = jac[:, 0, 0] * jac[:, 1, 1] - jac[:, 0, 1] * jac[:, 1, 0]
            with np.errstate(divide="ignore", invalid="ignore"):
                step = (
                    np.stack(
                        [
                            jac[:, 1, 1] * residual[:, 0] - jac[:, 0, 1] * residual[:, 1],
                            jac[:, 0, 0] * residual[:, 1] - jac[:, 1, 0] * residual[:, 0],
                        ],
                        axis=-1,
                    )
                    / det[:, None]
                )
            x[active] = xa - step
            size = np.abs(step).max(axis=-1)
            converged = size <= _TOLERANCE
            done[active[converged]] = True
            active = active[np.isfinite(size) & ~converged]
        x[~done] = np.nan
        lon = x[:, 0] * self.long_scale + self.long_off
        lat = x[:, 1] * self.lat_scale + self.lat_off
        return lon.reshape(shape), lat.reshape(shape)
