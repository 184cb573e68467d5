"""Caches are reused only by the code that made them (``provenance.code_version``)."""

import json
import shutil
import warnings

import numpy as np
import pytest

import wmr_jax as w
from wmr_jax import tuning
from wmr_jax._src import provenance
from wmr_jax._src.studies import sweep_files
from wmr_jax._src.tuning.trainer import differences


@pytest.fixture
def source_copy(tmp_path, monkeypatch):
    """A copy of the package's source that the digest reads instead of the real one."""
    copy = tmp_path / "src"
    shutil.copytree(provenance._SOURCE, copy, ignore=shutil.ignore_patterns("__pycache__"))
    monkeypatch.setattr(provenance, "_SOURCE", copy)
    provenance.code_version.cache_clear()
    yield copy
    provenance.code_version.cache_clear()


def test_the_code_version_follows_the_computing_source_only(source_copy):
    before = provenance.code_version()
    assert before.startswith(f"{w.__version__}+") and len(before.split("+")[1]) == 16
    # A figure or a command changes no number: the same version.
    with (source_copy / "report" / "maps.py").open("a") as f:
        f.write("\n# another colour\n")
    provenance.code_version.cache_clear()
    assert provenance.code_version() == before
    # The law does: another version.
    with (source_copy / "model" / "controllers" / "shim_sung.py").open("a") as f:
        f.write("\n# a changed law\n")
    provenance.code_version.cache_clear()
    assert provenance.code_version() != before


def test_a_checkpoint_of_other_code_is_another_run_and_says_so():
    now = tuning.run_identity()
    assert now["code"] == provenance.code_version()
    saved = {**now, "code": "0.1.0+0123456789abcdef"}
    assert differences(saved, now) == (
        f"computed by wmr_jax 0.1.0+0123456789abcdef, this is {now['code']}"
    )


def test_a_resumed_sweep_of_other_code_recomputes_with_a_warning(tmp_path, monkeypatch):
    refs = np.array([[30.0, 20.0, 0.5], [-10.0, 25.0, 2.0], [5.0, -40.0, -1.0]])
    first = w.sweep(refs, out=tmp_path, steps=20, chunk_size=2)
    chunks = sorted(tmp_path.glob("chunk_*.npz"))
    assert len(chunks) == 2
    manifest = json.loads((tmp_path / "sweep.json").read_text())
    monkeypatch.setattr(sweep_files, "code_version", lambda: "0.1.0+another-law")
    with pytest.warns(sweep_files.OtherSettingsWarning, match="version"):
        again = w.sweep(refs, out=tmp_path, steps=20, chunk_size=2)
    # Recomputed (here by the same law, so the same numbers), and now of the new code.
    for name in first:
        np.testing.assert_array_equal(again[name], first[name])
    assert json.loads((tmp_path / "sweep.json").read_text())["version"] != manifest["version"]
    with warnings.catch_warnings():
        warnings.simplefilter("error", sweep_files.OtherSettingsWarning)  # reused, no word
        w.sweep(refs, out=tmp_path, steps=20, chunk_size=2)
