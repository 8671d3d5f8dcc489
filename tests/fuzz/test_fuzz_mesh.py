"""Broken mesh files given to `--mesh-dir`: the loader gives a sane mug or one line naming the file.

A successful load is checked in the loader itself (`ndfa.sim.mesh_io.load_mug_dir`: rendering a
scene per input would take a minute); a failing one also through `ndfa ingest sim --mesh-dir`,
which loads the meshes before it renders anything."""

from __future__ import annotations

import tempfile
import warnings
from pathlib import Path

import pytest
from hypothesis import given

from ndfa.core.errors import NdfaError
from tests.fuzz.mesh_inputs import finite_mug, mesh_files
from tests.fuzz.property import CHECKED, _deadline, check_cli, kept_on_failure

pytestmark = pytest.mark.fuzz


def test_broken_mesh_files(fuzz_settings):
    from ndfa.sim.mesh_io import load_mug_dir

    @fuzz_settings
    @given(mesh_files())
    def run(mesh: tuple[str, bytes]) -> None:
        suffix, data = mesh
        with tempfile.TemporaryDirectory() as scratch:
            folder = Path(scratch) / "meshes"
            folder.mkdir()
            path = folder / f"mug{suffix}"
            path.write_bytes(data)
            with kept_on_failure(path):
                try:
                    with _deadline(10.0), warnings.catch_warnings():
                        warnings.simplefilter("ignore")  # "not watertight" is a warning by design
                        mugs = load_mug_dir(folder)
                except NdfaError as error:
                    message = str(error)
                    assert "\n" not in message and str(path) in message, message
                    out = Path(scratch) / "out"
                    check_cli(["ingest", "sim", "--preset", "sample", "--mesh-dir", str(folder), "--out", str(out)],
                              [str(path), str(folder)])
                    return
                CHECKED["mesh load"] += 1
                assert len(mugs) == 1 and finite_mug(mugs[0]), f"{path}: loaded, but not a sane mug"

    run()
