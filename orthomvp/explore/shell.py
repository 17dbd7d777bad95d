"""The ``mvp>`` command interpreter of ``orthomvp explore`` (interactive, or fed a script)."""

from __future__ import annotations

import cmd
import inspect
import math
import sys
from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np

from orthomvp.errors import OrthoMVPError
from orthomvp.explore.plots import Plot, height_plot, patches_plot, sweep_plot, tilt_plot
from orthomvp.explore.session import ExploreError, Explorer

RPLOT_RANGE_POSTS = 5.0  # default rplot half-range, in post spacings
RPLOT_STEPS = 101
LLPLOT_RANGE = 20.0  # default llplot half-range, degrees of tilt
LLPLOT_STEPS = 41


def _numbers(arg: str, kinds: tuple[type, ...], command: str) -> list:
    """Parse whitespace-separated arguments as ``kinds`` (all of them or none)."""
    words = arg.split()
    if not words:
        return []
    if len(words) > len(kinds):
        raise ExploreError(f"{command}: too many arguments ({arg!r}); see help {command}")
    try:
        values = [kind(w) for kind, w in zip(kinds, words, strict=False)]
    except ValueError:
        raise ExploreError(f"{command}: {arg!r} is not a number; see help {command}") from None
    if any(isinstance(v, float) and not math.isfinite(v) for v in values):
        raise ExploreError(f"{command}: arguments must be finite")
    return values


class ExplorerShell(cmd.Cmd):
    """Commands of the objective explorer; ``strict`` makes errors raise (scripts) instead of
    printing and going on (interactive). ``save`` never writes onto one of the session's
    ``inputs`` ((label, path) pairs: DEM, images, cameras) and replaces an existing file only
    with ``overwrite`` (``explore --overwrite``)."""

    prompt = "mvp> "
    doc_header = "Commands (help COMMAND for details):"
    undoc_header = None

    def __init__(
        self,
        explorer: Explorer,
        stdout: TextIO | None = None,
        strict: bool = False,
        *,
        inputs: Sequence[tuple[str, Path | str | None]] = (),
        overwrite: bool = False,
    ):
        super().__init__(stdout=stdout or sys.stdout)
        self.ex = explorer
        self.strict = strict
        self.inputs = list(inputs)
        self.overwrite = overwrite
        self.plot: Plot | None = None
        self.last_plot: tuple[str, str] | None = None

    # ------------------------------------------------------------------ plumbing
    def say(self, text: str) -> None:
        self.stdout.write(text + "\n")
        self.stdout.flush()

    def onecmd(self, line: str) -> bool:
        try:
            return bool(super().onecmd(line))
        except OrthoMVPError as exc:
            if self.strict:
                raise
            self.say(f"error: {exc}")
            return False

    def do_help(self, arg: str) -> None:
        """help [command]
        List the commands, or show one command's arguments, units and defaults."""
        name = arg.strip()
        if not name:
            super().do_help("")
            return
        method = getattr(self, f"do_{name}", None)
        if method is None or name == "EOF":
            raise ExploreError(f"help: no command {name!r} (type help for the list)")
        usage, *text = (inspect.getdoc(method) or name).splitlines()
        self.say("\n".join([usage, *("    " + line for line in text)]))

    def emptyline(self) -> bool:
        return False

    def default(self, line: str) -> bool:
        raise ExploreError(f"unknown command {line.split()[0]!r} (type help for the list)")

    def get_names(self) -> list[str]:
        return [n for n in dir(self.__class__) if n != "do_EOF"]

    def _where(self, window: bool = True) -> str:
        c, r = self.ex.poi
        lon, lat = self.ex.post_lonlat()
        where = f"post (c {c}, r {r}), lon {lon:.4f}, lat {lat:.4f} deg"
        if not window:
            return where
        n = int(self.ex.active_views().sum())
        return f"{where}; hwin {self.ex.hwin}, sigma {self.ex.window_sigma:g} posts; {n} views"

    def _show(self, plot: Plot, command: str, arg: str) -> None:
        self.plot = plot
        self.last_plot = (command, arg)

    # ------------------------------------------------------------------ commands
    def do_poi(self, arg: str) -> None:
        """poi [c r | lon lat]
        Show or set the point of interest, a DEM post. Two integers are a column and row
        (0-based, pixel centres); numbers with a decimal point are longitude and latitude in
        degrees (the nearest post is taken). Starts at the DEM centre. Setting it resets the
        current plane to the DEM's tangent plane there."""
        words = arg.split()
        if words:
            if len(words) != 2:
                raise ExploreError("poi takes two values: c r (integers) or lon lat (degrees)")
            if all(w.lstrip("+-").isdigit() for w in words):
                c, r = int(words[0]), int(words[1])
            else:
                lon, lat = _numbers(arg, (float, float), "poi")
                c, r = self.ex.lonlat_to_post(lon, lat)
            self.ex.set_poi(c, r)
        c, r = self.ex.poi
        lon, lat = self.ex.post_lonlat()
        seen = [n for n, v in zip(self.ex.names, self.ex.visible, strict=True) if v]
        self.say(
            f"poi: post (c {c}, r {r}), lon {lon:.5f}, lat {lat:.5f} deg; DEM value "
            f"{self.ex.terrain.values[r, c]:.2f} m; visible in {len(seen)} of "
            f"{len(self.ex.names)} views ({', '.join(seen) or 'none'})"
        )

    def do_hwin(self, arg: str) -> None:
        """hwin [n]
        Show or set the window half-size in posts (default 10): patches are 2n+1 posts
        across. The Gaussian window's sigma follows as n/2 unless set with sigma."""
        values = _numbers(arg, (int,), "hwin")
        if values:
            if not 1 <= values[0] <= 200:
                raise ExploreError("hwin must be an integer from 1 to 200")
            self.ex.hwin = values[0]
        self._say_window()

    def do_sigma(self, arg: str) -> None:
        """sigma [s | auto]
        Show or set the Gaussian window's standard deviation in posts (default: hwin/2;
        'auto' returns to that)."""
        if arg.strip() == "auto":
            self.ex.sigma = None
        else:
            values = _numbers(arg, (float,), "sigma")
            if values:
                if not values[0] > 0:
                    raise ExploreError("sigma must be positive (posts)")
                self.ex.sigma = values[0]
        self._say_window()

    def _say_window(self) -> None:
        auto = " (hwin/2)" if self.ex.sigma is None else ""
        self.say(
            f"hwin {self.ex.hwin} posts ({2 * self.ex.hwin + 1} x {2 * self.ex.hwin + 1} "
            f"samples), sigma {self.ex.window_sigma:g} posts{auto}"
        )

    def do_cp(self, arg: str) -> None:
        """cp [h n_theta n_phi]
        Show or set the current plane: its height at the post h (metres, in the DEM's
        convention) and its normal as eq. (11) angles n_theta (longitude) and n_phi
        (latitude) in degrees. Shown with the normal's tilts towards east and north and
        the objective there."""
        values = _numbers(arg, (float, float, float), "cp")
        if values:
            if len(values) != 3:
                raise ExploreError("cp takes three values: h n_theta n_phi")
            self.ex.set_plane(*values)
        self._say_plane("current plane")

    def _say_plane(self, label: str) -> None:
        nt, nphi, te, tn = self.ex.plane_angles()
        W = self.ex.active_views()
        cost = self.ex.evaluate(self.ex.theta, W).cost[0] if W.sum() >= 2 else np.inf
        self.say(
            f"{label}: h {self.ex.theta[0]:.3f} m, n_theta {nt:.4f}, n_phi {nphi:.4f} deg "
            f"(tilt east {te:.3f}, north {tn:.3f} deg); f {cost:.5g} with {int(W.sum())} views"
        )

    def do_cpi(self, arg: str) -> None:
        """cpi
        Reset the current plane to the DEM's tangent plane at the point of interest."""
        _numbers(arg, (), "cpi")
        self.ex.reset_plane()
        self._say_plane("current plane")

    def do_rplot(self, arg: str) -> None:
        """rplot [range [steps]]
        Plot the objective against the plane's height with its orientation held, over
        +-range metres around the current plane (default 5 post spacings) in steps
        samples (default 101). Marks the current plane, the minimum and, after fit, the
        optimiser's path."""
        values = _numbers(arg, (float, int), "rplot")
        half = values[0] if values else RPLOT_RANGE_POSTS * self.ex.spacing
        steps = values[1] if len(values) > 1 else RPLOT_STEPS
        curve = self.ex.height_curve(half, steps)
        h = self.ex.theta[0]
        self._show(height_plot(curve, h, self._where(), self.ex.path), "rplot", arg)
        self.say(
            f"rplot: minimum at h {curve.h_min:.3f} m ({curve.h_min - h:+.3f} from the current "
            f"plane), f {curve.cost_min:.5g}; curvature {curve.curvature:.3g} per m^2; "
            f"local minima over +-{half:g} m: {curve.local_minima}"
        )

    def do_llplot(self, arg: str) -> None:
        """llplot [range [steps]]
        Plot the objective over a steps x steps grid of normal orientations (default 41)
        within +-range degrees (default 20) of the current plane's tilts towards east and
        north, the height held; darker is lower cost. Marks the current plane, the
        minimum and, after fit, the optimiser's path."""
        values = _numbers(arg, (float, int), "llplot")
        half = values[0] if values else LLPLOT_RANGE
        steps = values[1] if len(values) > 1 else LLPLOT_STEPS
        surf = self.ex.tilt_surface(half, steps)
        _, _, te, tn = self.ex.plane_angles()
        self._show(tilt_plot(surf, (te, tn), self._where(), self.ex.path), "llplot", arg)
        i = int(np.argmin(np.abs(surf.north - surf.north_min)))
        j = int(np.argmin(np.abs(surf.east - surf.east_min)))
        self.say(
            f"llplot: minimum at tilt east {surf.east_min:.3f}, north {surf.north_min:.3f} deg "
            f"(n_theta {surf.n_theta[i, j]:.4f}, n_phi {surf.n_phi[i, j]:.4f} deg), "
            f"f {surf.cost[i, j]:.5g}"
        )

    def do_replot(self, arg: str) -> None:
        """replot
        Redraw the last plot with the current settings (point, plane, window)."""
        _numbers(arg, (), "replot")
        if self.last_plot is None:
            raise ExploreError("replot: nothing plotted yet")
        command, previous = self.last_plot
        getattr(self, f"do_{command}")(previous)

    def do_save(self, arg: str) -> None:
        """save FILE
        Save the last plot (PNG, SVG or PDF by the file's extension) and its data beside it
        as CSV (same name, .csv). Neither may be an input (DEM, image, camera); a file that
        exists is replaced only when explore was started with --overwrite."""
        if not arg.strip():
            raise ExploreError("save needs a file name, e.g. save rplot.png")
        if self.plot is None:
            raise ExploreError("save: nothing plotted yet")
        try:
            figure, data = self.plot.save(
                arg.strip(),
                inputs=self.inputs,
                overwrite=self.overwrite,
                overwrite_hint="start explore with --overwrite",
            )
        except OSError as exc:
            raise ExploreError(f"save: {exc}") from exc
        self.say(f"wrote {figure} and {data}")

    def do_views(self, arg: str) -> None:
        """views
        List every view at the point of interest: visibility (from the ray-cast test),
        emission angle (degrees from the surface normal), ground sample distance
        (m/pixel), whether it takes part in the objective at the current plane and its
        patch's correlation with the mean of the others (leave-one-out)."""
        _numbers(arg, (), "views")
        self.say(f"{'view':<20} {'visibility':<18} {'emission':>9} {'GSD m/px':>9}  used  corr")
        for v in self.ex.views():
            corr = "" if math.isnan(v.loo) else f"{v.loo:.3f}"
            self.say(
                f"{v.name:<20} {v.code:<18} {v.emission:>9.2f} {v.gsd:>9.2f}  "
                f"{'yes ' if v.used else 'no  '}  {corr}"
            )

    def do_patches(self, arg: str) -> None:
        """patches
        Show the normalised orthoimage patches (eq. 19) of the views taking part at the
        current plane and their mean, the albedo (eq. 21), side by side."""
        _numbers(arg, (), "patches")
        names, patches, albedo, loo, cost = self.ex.patches()
        plot = patches_plot(names, patches, albedo, list(loo), self._where())
        self._show(plot, "patches", arg)
        self.say(f"patches: {len(names)} views ({', '.join(names)}), f {cost:.5g}")

    def do_fit(self, arg: str) -> None:
        """fit
        Run the optimiser (coarse-to-fine Levenberg-Marquardt, as orthomvp fit, without
        outlier rejection) from the current plane, print every iteration, and make the
        result the current plane. The next rplot / llplot shows the path."""
        _numbers(arg, (), "fit")
        path, trace = self.ex.fit()
        self.say(f"{'iter':>4} {'level':>5} {'h m':>12} {'east':>8} {'north':>8} "
                 f"{'f(level)':>10} {'lambda':>8}  step")  # fmt: skip
        for k, it in enumerate(trace, 1):
            t = it.trial[0]
            e, n = np.degrees(np.arctan(t[1:]))
            self.say(
                f"{k:>4} {it.level:>5} {t[0]:>12.3f} {e:>8.3f} {n:>8.3f} {it.cost[0]:>10.5g} "
                f"{it.lam[0]:>8.1e}  {'accepted' if it.accepted[0] else 'rejected'}"
            )
        self._say_plane(f"fit: {len(path) - 1} steps accepted; current plane")

    def do_sweep(self, arg: str) -> None:
        """sweep hwin a b [step]
        For window half-sizes a..b posts (step default 1, or (b-a)/12 when wider), the
        rplot curve at the current plane: where the height minimum falls, how sharp it is
        (curvature, cost per m^2) and how many local minima appear. Sigma is hwin/2 unless
        set with sigma. Small windows give local minima (the mvpgui paper's figure 12)."""
        words = arg.split()
        if not words or words[0] != "hwin":
            raise ExploreError("usage: sweep hwin a b [step]")
        values = _numbers(" ".join(words[1:]), (int, int, int), "sweep")
        if len(values) < 2 or not 1 <= values[0] <= values[1] <= 200:
            raise ExploreError("sweep hwin a b: need 1 <= a <= b <= 200")
        a, b = values[:2]
        step = values[2] if len(values) > 2 else max(1, math.ceil((b - a) / 12))
        if step < 1:
            raise ExploreError("sweep: step must be >= 1")
        hwins = list(range(a, b + 1, step))
        half = RPLOT_RANGE_POSTS * self.ex.spacing
        results = self.ex.sweep(hwins, half, RPLOT_STEPS)
        self._show(sweep_plot(results, self._where(window=False)), "sweep", arg)
        self.say(f"{'hwin':>4} {'sigma':>6} {'h_min m':>12} {'f_min':>9} {'curv/m^2':>10} minima")
        for h, s, c in results:
            self.say(
                f"{h:>4} {s:>6g} {c.h_min:>12.3f} {c.cost_min:>9.4g} {c.curvature:>10.3g} "
                f"{c.local_minima:>6}"
            )

    def do_exit(self, arg: str) -> bool:
        """exit
        Leave the explorer (also quit, or end of input)."""
        return True

    do_quit = do_exit

    def do_EOF(self, arg: str) -> bool:  # noqa: N802
        self.say("")
        return True


def split_commands(text: str) -> list[str]:
    """Commands from a script or ``-c`` text: one per line or separated by ';'; '#' starts a
    comment."""
    out = []
    for line in text.splitlines():
        line = line.split("#", 1)[0]
        out.extend(part.strip() for part in line.split(";") if part.strip())
    return out


def run_commands(shell: ExplorerShell, commands: Iterable[str]) -> None:
    """Run commands in order, stopping at exit; the first failing one raises ExploreError
    naming it."""
    shell.strict = True
    for k, line in enumerate(commands, 1):
        try:
            if shell.onecmd(line):
                return
        except OrthoMVPError as exc:
            raise ExploreError(f"explore: command {k} ({line!r}): {exc}") from exc
