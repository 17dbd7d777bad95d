"""A script that starts a run on worker processes without the ``__main__`` guard: every
spawned worker imports the script again, and so starts a run of its own and dies while it
starts. The run ends in bounded time with one error naming the guard (it used to block for
good writing the plan to a worker that had died), and a guarded script runs."""

from __future__ import annotations

import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow

SECONDS = 120


def _script(folder: Path, scene: Path, body: str, *, guarded: bool) -> Path:
    code = textwrap.dedent(
        f"""
        import orthomvp as om

        def main():
            plan = om.plan_ortho({str(scene / "dem.tif")!r},
                [({str(scene / "oblique.tif")!r}, {str(scene / "oblique.tsai")!r})],
                progress=False)
            {body}
        """
    )
    code += 'if __name__ == "__main__":\n    main()\n' if guarded else "main()\n"
    path = folder / ("guarded.py" if guarded else "unguarded.py")
    path.write_text(code)
    return path


def _run(script: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, str(script)], capture_output=True, text=True, timeout=SECONDS,
        cwd=script.parent,
    )  # fmt: skip


def test_processes_without_the_guard_end_with_one_error(crater_dir: Path, tmp_path: Path) -> None:
    out = tmp_path / "o.tif"
    body = f"om.run_plan(plan, om.Outputs(ortho={str(out)!r}), processes=2)"
    proc = _run(_script(tmp_path, crater_dir, body, guarded=False))
    assert proc.returncode == 1
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("orthomvp.engine.cluster.WorkerError: a worker died"), last
    assert "unguarded.py" in last and 'if __name__ == "__main__":' in last
    assert not out.exists()
    good = _run(_script(tmp_path, crater_dir, body, guarded=True))
    assert good.returncode == 0, good.stderr
    assert out.exists()


def test_a_local_dask_cluster_without_the_guard_is_one_input_error(
    crater_dir: Path, tmp_path: Path
) -> None:
    pytest.importorskip("distributed")
    body = "from orthomvp.engine.cluster import dask_client; dask_client(workers=1).__enter__()"
    script = _script(tmp_path, crater_dir, body, guarded=False)
    proc = _run(script)
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("orthomvp.errors.InputError: the local Dask cluster's workers"), last
    assert 'if __name__ == "__main__":' in last


def test_a_local_dask_cluster_whose_workers_fail_rerunning_the_script(
    crater_dir: Path, tmp_path: Path
) -> None:
    """The docs' engine example without the guard: each worker runs the script again, whose
    first run_plan now refuses the output the parent wrote (an InputError in the worker, not
    multiprocessing's bootstrapping message); the parent still names the guard."""
    pytest.importorskip("distributed")
    out = tmp_path / "first.tif"
    body = (
        f"om.run_plan(plan, om.Outputs(ortho={str(out)!r}), threads=1); "
        "from orthomvp.engine.cluster import dask_client; dask_client(workers=1).__enter__()"
    )
    proc = _run(_script(tmp_path, crater_dir, body, guarded=False))
    last = proc.stderr.strip().splitlines()[-1]
    assert last.startswith("orthomvp.errors.InputError: the local Dask cluster's workers"), last
    assert "running the main script again, as every worker does, they failed (" in last
    assert "the output file of ortho exists" in last and 'if __name__ == "__main__":' in last


def test_the_guard_is_named_only_where_it_can_be_the_cause(
    monkeypatch: pytest.MonkeyPatch,
) -> None:
    """Found in review: every worker death got the hint, under the command line too. Only a
    pool broken before any tile came back, under a script run as a file, names the guard."""
    import concurrent.futures as cf
    import types

    from orthomvp.engine.cluster import WorkerError, worker_deaths

    def message(main: types.ModuleType, *, started: bool) -> str:
        monkeypatch.setitem(sys.modules, "__main__", main)
        with pytest.raises(WorkerError) as caught, worker_deaths(started=started):
            raise cf.process.BrokenProcessPool("a process died")
        return str(caught.value)

    script = types.ModuleType("__main__")
    script.__file__, script.__spec__ = "/home/me/run.py", None
    assert "if run.py starts this run at import" in message(script, started=False)
    assert "__main__" not in message(script, started=True)
    entry = types.ModuleType("__main__")
    entry.__file__, entry.__spec__ = "/venv/bin/orthomvp", None
    assert "__main__" not in message(entry, started=False)
    module = types.ModuleType("__main__")
    module.__file__, module.__spec__ = "/x/pkg/__main__.py", object()
    assert "__main__" not in message(module, started=False)


def test_plan_folders_of_killed_runs_are_removed(
    crater_dir: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """Found in review: the plan's folder for the worker processes stayed in the temporary
    folder when the run was killed outright (SIGKILL runs no cleanup). The next run removes
    those of processes that are gone, keeps a live one's, and leaves none of its own."""
    import os
    import tempfile

    import orthomvp as om
    from orthomvp.io.outputs import _HOST

    scratch = tmp_path / "tmp"
    scratch.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(scratch))
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True, check=True)  # fmt: skip
    dead = scratch / f"orthomvp-plan-{int(gone.stdout)}-{_HOST}-abc"
    live = scratch / f"orthomvp-plan-{os.getppid()}-{_HOST}-def"
    for folder in (dead, live):
        folder.mkdir()
        (folder / "plan.pickle").write_bytes(b"x" * 100)
    d = crater_dir
    plan = om.plan_ortho(d / "dem.tif", [(d / "oblique.tif", d / "oblique.tsai")], progress=False)
    om.run_plan(plan, om.Outputs(ortho=tmp_path / "o.tif"), processes=2, progress=False)
    assert sorted(p.name for p in scratch.iterdir()) == [live.name]
