"""The Gaussian window of the MVP objective (eqs. 20-21): where a patch is sampled and how much
each sample weighs."""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from orthomvp.errors import InputError


@dataclass(frozen=True, eq=False)
class Window:
    """A (2 hwin + 1) x (2 hwin + 1) patch grid with Gaussian weights, built from ``hwin`` and
    ``sigma`` (validated: hwin >= 1, sigma > 0).

    Units are patch steps: one step is one DEM post at pyramid level 0 and 2**L posts at level
    L. ``hwin``: half-size; ``sigma``: the Gaussian's standard deviation. ``offsets`` (S, 2)
    float32: the samples' (c, r) offsets from the post, c running fastest; ``weights`` (S,)
    float32: exp(-|offset|^2 / (2 sigma^2)), normalised to sum 1.
    """

    hwin: int
    sigma: float
    offsets: np.ndarray = field(init=False, repr=False)
    weights: np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.hwin < 1 or not self.sigma > 0:
            raise InputError(
                f"hwin must be >= 1 and sigma > 0, got hwin={self.hwin}, sigma={self.sigma}"
            )
        j, i = np.mgrid[-self.hwin : self.hwin + 1, -self.hwin : self.hwin + 1]
        offsets = np.stack([i.ravel(), j.ravel()], axis=-1).astype(np.float32)
        g = np.exp(-(offsets**2).sum(axis=1) / (2.0 * self.sigma**2))
        object.__setattr__(self, "offsets", offsets)
        object.__setattr__(self, "weights", (g / g.sum()).astype(np.float32))

    @property
    def side(self) -> int:
        """Samples across the patch, 2 hwin + 1."""
        return 2 * self.hwin + 1
