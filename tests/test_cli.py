"""The command line: subcommands, documented options, one-line errors with exit status 2 (130
on Ctrl-C), no half-written output. Commands run in this process through ``main``; one test
runs the real entry point, ``python -m orthomvp``, in a subprocess."""

from __future__ import annotations

import json
import subprocess
import sys
from contextlib import redirect_stderr, redirect_stdout
from dataclasses import dataclass
from io import StringIO
from pathlib import Path

import click
import numpy as np
import pytest
import rasterio
import trimesh
from affine import Affine

from orthomvp.cli import cli, main
from orthomvp.cli.command import spell_out

COMMANDS = (
    "demo", "info", "synth", "mesh", "render", "visibility", "ortho", "mosaic", "explore", "fit",
    "eps-study", "check", "isd", "bench", "view",
)  # fmt: skip


@dataclass
class Result:
    """Exit status and output of one command line."""

    returncode: int
    stdout: str
    stderr: str


def run(*args: str) -> Result:
    """Run ``orthomvp ARGS`` in this process, as the entry point does."""
    out, err = StringIO(), StringIO()
    with redirect_stdout(out), redirect_stderr(err):
        status = main(list(args))
    return Result(status, out.getvalue(), err.getvalue())


def assert_one_line_error(proc: Result | subprocess.CompletedProcess, *words: str) -> None:
    assert proc.returncode == 2, proc.stderr
    # the error is one line, the last; before it only the engine's plan line may stand
    lines = [x for x in proc.stderr.strip().splitlines() if not x.startswith("orthomvp: plan:")]
    assert len(lines) == 1, proc.stderr
    assert lines[0].startswith("orthomvp: error:")
    assert proc.stderr.strip().splitlines()[-1] == lines[0]
    assert "Traceback" not in proc.stderr
    for word in words:
        assert word in lines[0], lines[0]


def test_entry_point_in_a_subprocess() -> None:
    def entry(*args: str) -> subprocess.CompletedProcess:
        cmd = [sys.executable, "-m", "orthomvp", *args]
        return subprocess.run(cmd, capture_output=True, text=True, timeout=120)

    proc = entry("--help")
    assert proc.returncode == 0, proc.stderr
    for cmd in COMMANDS:
        assert f"\n  {cmd} " in proc.stdout
    assert_one_line_error(entry("synth", "volcano", "x"), "synth: ", "'volcano'", "crater")


def test_entry_point_sets_the_garbage_collection_up() -> None:
    """The console-script entry point leaves the imports' objects out of collection and
    collects young objects every GC_THRESHOLD allocations (seen from an exit handler, which it
    runs before os._exit)."""
    code = (
        "import atexit, gc, sys\n"
        "atexit.register(lambda: print(gc.get_threshold()[0], gc.get_freeze_count() > 1000))\n"
        "from orthomvp.cli import GC_THRESHOLD, main_entry\n"
        "print(GC_THRESHOLD)\n"
        "sys.argv = ['orthomvp', '--version']\n"
        "main_entry()\n"
    )
    threshold, version, seen = python(code).stdout.splitlines()
    assert version.startswith("orthomvp ") and int(threshold) > 700
    assert seen == f"{threshold} True"


def python(code: str) -> subprocess.CompletedProcess:
    """``code`` run by a fresh interpreter, which must succeed."""
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0, proc.stderr
    return proc


def test_a_command_imports_its_own_module_only() -> None:
    """A command's run (here its --help) imports its module, not every other command's; the
    group's --help lists them all, each under its own name."""
    code = (
        "import sys\n"
        "from orthomvp.cli import main\n"
        "main(['ortho', '--help'])\n"
        "print(sorted(m for m in sys.modules if m.startswith('orthomvp.cli.')))\n"
        "main(['--help'])\n"
        "import click, orthomvp.cli\n"
        "from orthomvp.cli import cli\n"
        "cli.add_command(click.Command('extra'))\n"
        "assert orthomvp.cli.fit.fit is cli.commands['fit'] and 'extra' in cli.commands\n"
        "print(all(command.name == name for name, command in cli.commands.items()))\n"
    )
    proc = python(code)
    lines = proc.stdout.splitlines()
    loaded = eval(next(line for line in lines if line.startswith("['orthomvp.cli.")))  # noqa: S307
    assert "orthomvp.cli.ortho" in loaded
    assert not {"orthomvp.cli.bench", "orthomvp.cli.fit", "orthomvp.cli.check"} & set(loaded)
    assert all(f"  {name} " in proc.stdout for name in COMMANDS) and lines[-1] == "True"
    # (and a command added later, and the modules as attributes of orthomvp.cli)


def test_help_documents_every_argument_and_option() -> None:
    assert tuple(cli.commands) == COMMANDS
    assert run("--version").stdout.startswith("orthomvp ")
    root = cli.make_context("orthomvp", [], resilient_parsing=True)
    for name, command in cli.commands.items():
        proc = run(name, "--help")
        assert proc.returncode == 0 and proc.stdout.startswith(f"Usage: orthomvp {name} ")
        text = "".join(proc.stdout.split())  # as wrapped: compare without spaces
        ctx = command.make_context(name, [], parent=root, resilient_parsing=True)
        for param in command.params:
            assert param.help, f"{name}: {param.name} has no help"
            record = "".join(param.get_help_record(ctx)[1].split())
            assert record in text
            if isinstance(param, click.Option) and (
                isinstance(param.show_default, str)
                or ctx.params[param.name] not in (None, False, ())
            ):
                assert "[default:" in record, f"{name}: {param.name} does not show its default"
            # every number has its valid range checked where it is defined, and shown
            assert param.type not in (click.INT, click.FLOAT), f"{name}: {param.name} unbounded"
            if isinstance(param.type, click.types._NumberRangeBase):
                described = "".join(param.type._describe_range().split())
                assert described in record, f"{name}: {param.name} does not show {described}"


def test_choices_match_the_library() -> None:
    from orthomvp import synthetic
    from orthomvp.cli import mesh as mesh_cli
    from orthomvp.cli import synth as synth_cli
    from orthomvp.present import colours

    assert synth_cli.KINDS == synthetic.KINDS and mesh_cli.COLOUR_KINDS == colours.COLOUR_KINDS
    # the ranges the command line checks are the library's
    from orthomvp.cli import fit as fit_cli
    from orthomvp.cli import render as render_cli
    from orthomvp.mvp import fit as fit_lib
    from orthomvp.present import export, snapshot
    from orthomvp.synthetic import rendering, scene

    assert (synth_cli.SPACING_RANGE, synth_cli.GSD_RATIO_RANGE, synth_cli.MAX_SUPERSAMPLE) == (
        scene.SPACING_RANGE,
        scene.GSD_RATIO_RANGE,
        rendering.MAX_SUPERSAMPLE,
    )
    assert render_cli.MAX_RAYS == snapshot.MAX_RAYS
    assert mesh_cli.MESH_SUFFIXES == export.EXPORT_FORMATS
    deconvolve = next(p for p in fit_cli.fit.params if p.name == "deconvolve")
    assert deconvolve.type.max == fit_lib.MAX_DECONVOLVE


def test_usage_errors_are_one_line(tmp_path: Path) -> None:
    assert_one_line_error(run("synth", "volcano", "x"), "synth: ", "'volcano' is not one of")
    assert_one_line_error(run("mesh", "dem.tif"), "mesh: ", "'--output'")
    assert_one_line_error(run("mesh", "dem.tif", "-o", "x.ply", "--bogus"), "--bogus")
    assert_one_line_error(run("synth", "crater", "x", "--size", "4"), "--size", "x>=8")
    assert_one_line_error(run("synth", "crater", "x", "--spacing", "nan"), "not a finite number")
    assert_one_line_error(run("render", "dem.tif", "-o", "x.png", "--size", "9", "9"), "16<=x")
    assert_one_line_error(run("eps-study", "s", "--dem-noise", "1", "-2"), "--dem-noise")
    assert_one_line_error(run("explore", "d", "i", "c", "-c", "x", "--script", "f"), "not allowed")
    assert_one_line_error(run("nonsense"), "No such command 'nonsense'")
    for args in ((), ("-q",)):  # no command: a usage error, as rio has it, in one line
        proc = run(*args)
        assert_one_line_error(proc, "no command given", "'orthomvp --help'")
        assert proc.stdout == ""
    assert not list(tmp_path.iterdir())


def test_options_with_several_values() -> None:
    words = ["s", "--eps", "1", "2", "-3", "--dem-noise", "0", "5", "-o", "p", "--eps", "7"]
    assert spell_out(words, {"--eps", "--dem-noise"}) == [
        "s", "--eps", "1", "--eps", "2", "--eps", "-3", "--dem-noise", "0", "--dem-noise", "5",
        "-o", "p", "--eps", "7",
    ]  # fmt: skip
    after_end = ["s", "--", "--eps", "1", "2"]
    assert spell_out(after_end, {"--eps"}) == after_end


def test_interrupts_and_internal_errors(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    import orthomvp.synthetic

    def stop(*args: object, **kwargs: object) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(orthomvp.synthetic, "make_scene", stop)
    proc = run("synth", "crater", str(tmp_path / "scene"))
    assert proc.returncode == 130 and proc.stderr.count("\n") == 1 and "interrupted" in proc.stderr

    def bug(*args: object, **kwargs: object) -> None:
        raise RuntimeError("a bug")

    monkeypatch.setattr(orthomvp.synthetic, "make_scene", bug)
    monkeypatch.delenv("ORTHOMVP_DEBUG", raising=False)
    proc = run("synth", "crater", str(tmp_path / "s"))  # a bug: status 1, one line
    assert proc.returncode == 1 and proc.stderr.count("\n") == 1, proc.stderr
    assert proc.stderr.startswith("orthomvp: internal error: RuntimeError: a bug;")
    monkeypatch.setenv("ORTHOMVP_DEBUG", "1")
    with pytest.raises(RuntimeError, match="a bug"):
        run("synth", "crater", str(tmp_path / "s"))
    assert not list(tmp_path.iterdir())


@pytest.mark.slow
def test_synth_then_mesh(tmp_path: Path) -> None:
    out = tmp_path / "scene"
    proc = run("synth", "hills", str(out), "--size", "24", "--supersample", "1")
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == f"orthomvp: wrote hills scene with 4 views to {out}\n"
    for name in ("dem.tif", "scene.json", "truth_radiance.tif", "fore1.tif", "fore1.tsai"):
        assert (out / name).is_file()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]
    ply = tmp_path / "hills.ply"
    proc = run(
        "mesh", str(out / "dem.tif"), "-o", str(ply), "--texture", str(out / "truth_radiance.tif")
    )
    assert proc.returncode == 0, proc.stderr
    mesh = trimesh.load(ply, process=False)
    assert len(mesh.faces) == 2 * 23 * 23 and len(mesh.vertices) == 24 * 24
    # body-fixed coordinates: every vertex is about one lunar radius from the centre
    radii = np.linalg.norm(mesh.vertices, axis=1)
    assert np.all(np.abs(radii - 1737400) < 5000)


@pytest.mark.slow
def test_mesh_bad_inputs_leave_nothing(tmp_path: Path) -> None:
    out = tmp_path / "out.ply"
    assert_one_line_error(
        run("mesh", str(tmp_path / "missing.tif"), "-o", str(out)), "missing.tif", "no such file"
    )
    (tmp_path / "corrupt.tif").write_bytes(b"II*\x00" + bytes(range(200)))
    assert_one_line_error(run("mesh", str(tmp_path / "corrupt.tif"), "-o", str(out)), "corrupt.tif")
    profile = dict(
        driver="GTiff",
        width=8,
        height=8,
        count=1,
        dtype="float32",
        transform=Affine(0.01, 0, 0, 0, -0.01, 0),
    )
    with rasterio.open(tmp_path / "nocrs.tif", "w", **profile) as dst:
        dst.write(np.zeros((8, 8), np.float32), 1)
    assert_one_line_error(run("mesh", str(tmp_path / "nocrs.tif"), "-o", str(out)), "no CRS")
    proc = run(
        "mesh", str(tmp_path / "nocrs.tif"), "-o", str(out), "--dem-crs", "+proj=longlat +R=1737400"
    )
    assert proc.returncode == 0, proc.stderr
    out.unlink()
    assert_one_line_error(
        run(
            "mesh",
            str(tmp_path / "nocrs.tif"),
            "-o",
            str(tmp_path / "out.stl"),
            "--dem-crs",
            "+proj=longlat +R=1737400",
        ),
        "-o writes a mesh",
    )
    assert_one_line_error(
        run(
            "mesh",
            str(tmp_path / "nocrs.tif"),
            "-o",
            str(tmp_path / "nodir" / "out.ply"),
            "--dem-crs",
            "+proj=longlat +R=1737400",
        ),
        "does not exist",
    )
    assert sorted(p.name for p in tmp_path.iterdir()) == ["corrupt.tif", "nocrs.tif"]


@pytest.mark.slow
def test_bench_prints_ratios(tmp_path: Path) -> None:
    proc = run(
        "bench",
        "--size",
        "60",
        "--rays",
        "20000",
        "--ortho-size",
        "80",
        "--mvp-size",
        "40",
        "--linescan-size",
        "80",
        "--linescan-points",
        "20000",
        "--json",
        str(tmp_path / "b.json"),
    )
    assert proc.returncode == 0, proc.stderr
    assert "embree" in proc.stdout and "open3d" in proc.stdout and "ratio" in proc.stdout
    assert "occlusion-aware orthophoto" in proc.stdout
    assert "MVP fit" in proc.stdout
    assert "line scan: ground to image of 20,000 points" in proc.stdout
    row = json.loads((tmp_path / "b.json").read_text())["linescan"]
    assert row["posts"] == 80 * 80 and row["table_error_px"] < 1e-4
    assert row["ratio"] == pytest.approx(row["linescan_ortho_s"] / row["frame_ortho_s"])


def test_bench_peer_data_default(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """--peer-data defaults to $ORTHOMVP_DATA/ngi-aerial, else to the synthetic scene (the
    peer run itself is replaced here: tests/test_bench_peer.py runs it)."""
    from orthomvp import bench

    used = []
    monkeypatch.setattr(bench, "import_orthority", lambda: None)
    monkeypatch.setattr(bench, "ngi_case", lambda data, work: used.append(data) or "ngi")
    monkeypatch.setattr(bench, "synthetic_case", lambda work: used.append(None) or "synthetic")
    monkeypatch.setattr(bench, "bench_orthority", lambda case, res, repeat: {"case": case})
    monkeypatch.setattr(bench, "format_orthority", lambda row: f"ran {row['case']}")
    monkeypatch.delenv("ORTHOMVP_DATA", raising=False)
    proc = run("bench", "--peer", "orthority")
    assert proc.returncode == 0, proc.stderr
    assert "using a synthetic aerial scene" in proc.stdout and "ran synthetic" in proc.stdout
    monkeypatch.setenv("ORTHOMVP_DATA", str(tmp_path))
    (tmp_path / "ngi-aerial").mkdir()
    (tmp_path / "ngi-aerial" / "dem.tif").touch()
    assert run("bench", "--peer", "orthority").stdout == "ran ngi\n"
    assert used == [None, tmp_path / "ngi-aerial"]
    assert "$ORTHOMVP_DATA/ngi-aerial" in "".join(run("bench", "--help").stdout.split())


def test_quiet_after_the_command(crater_dir: Path, tmp_path: Path) -> None:
    """``-q`` after the command (and its arguments) is ``-q`` before it: no summary, the same
    output; after ``--`` it is not an option."""
    from orthomvp.cli import quiet_first

    base = [
        "ortho", str(crater_dir / "dem.tif"), str(crater_dir / "oblique.tif"),
        str(crater_dir / "oblique.tsai"), "--grid", "dem",
    ]  # fmt: skip
    loud = run(*base, "-o", str(tmp_path / "a.tif"))
    quiet = run(*base, "-o", str(tmp_path / "b.tif"), "-q")
    assert loud.returncode == quiet.returncode == 0
    assert "wrote" in loud.stdout and quiet.stdout == ""
    with rasterio.open(tmp_path / "a.tif") as a, rasterio.open(tmp_path / "b.tif") as b:
        np.testing.assert_array_equal(a.read(), b.read())
    assert quiet_first(["ortho", "x", "--quiet", "--", "-q"]) == ["-q", "ortho", "x", "--", "-q"]
    assert quiet_first(["ortho", "x"]) == ["ortho", "x"]
