"""Result files: atomic writes, checksummed arrays, damaged files refused in one line."""

import json
import math

import numpy as np
import pytest

from wmr_jax import report
from wmr_jax._src.report.tables import json_number


def test_atomic_json_round_trip_keeps_infinities_readable(tmp_path):
    row = {"t": [1.0, math.inf, -math.inf, math.nan]}
    path = report.atomic_write_json(tmp_path / "sub" / "a.json", row)
    # NaN is written as "nan", not as null, which would not say what it was.
    assert json.loads(path.read_text()) == {"t": [1.0, "inf", "-inf", "nan"]}
    assert math.isnan(json_number("t", json.loads(path.read_text())["t"][3]))  # tables read it
    assert list(path.parent.iterdir()) == [path]  # no temporary file left behind


def test_a_failed_write_leaves_the_old_file_and_no_temporary(tmp_path):
    path = tmp_path / "a.npz"
    report.save_arrays(path, {"x": np.arange(3.0)}, {"run": 1})

    class Unsaveable:
        def __array__(self, *args, **kwargs):
            raise RuntimeError("disk full")

    with pytest.raises(RuntimeError):
        report.save_arrays(path, {"x": Unsaveable()}, {"run": 2})
    arrays, meta = report.load_arrays(path)
    np.testing.assert_array_equal(arrays["x"], np.arange(3.0))
    assert meta == {"run": 1}
    assert [p.name for p in tmp_path.iterdir()] == ["a.npz"]


def test_arrays_and_meta_round_trip(tmp_path):
    arrays = {"z": np.linspace(0, 1, 7), "i": np.arange(4, dtype=np.int32)}
    report.save_arrays(tmp_path / "c.npz", arrays, {"seed": 3, "name": "x", "t": math.inf})
    loaded, meta = report.load_arrays(tmp_path / "c.npz")
    assert meta == {"seed": 3, "name": "x", "t": "inf"}
    for name, value in arrays.items():
        np.testing.assert_array_equal(loaded[name], value)
        assert loaded[name].dtype == value.dtype


def damage(path, how):
    data = bytearray(path.read_bytes())
    if how == "truncated":
        data = data[: len(data) // 2]
    elif how == "empty":
        data = bytearray()
    elif how == "flipped byte":
        data[len(data) // 3] ^= 0xFF
    path.write_bytes(bytes(data))


@pytest.mark.parametrize("how", ["truncated", "empty", "flipped byte"])
def test_damaged_files_are_refused_in_one_line(tmp_path, how):
    path = tmp_path / "c.npz"
    report.save_arrays(path, {"z": np.arange(100.0)}, {"k": 1})
    damage(path, how)
    with pytest.raises(report.DamagedFileError, match="c.npz is damaged") as info:
        report.load_arrays(path)
    assert "\n" not in str(info.value)
    assert isinstance(info.value, ValueError)


def test_well_formed_but_altered_values_are_refused(tmp_path):
    path = tmp_path / "c.npz"
    report.save_arrays(path, {"z": np.arange(5.0)}, {"k": 1})
    with np.load(path) as data:
        stored = {name: data[name] for name in data.files}
    stored["z"] = stored["z"] + 1.0  # a valid .npz, with other numbers in it
    np.savez(path, **stored)
    with pytest.raises(report.DamagedFileError, match="checksum"):
        report.load_arrays(path)


def test_stale_temporaries_are_removed(tmp_path):
    (tmp_path / ".chunk_000001.npz.abc123.tmp").write_bytes(b"half")
    keep = tmp_path / "chunk_000000.npz"
    keep.write_bytes(b"x")
    removed = report.remove_stale_temporaries(tmp_path)
    assert [p.name for p in removed] == [".chunk_000001.npz.abc123.tmp"]
    assert [p.name for p in tmp_path.iterdir()] == [keep.name]


def test_another_kind_of_file_or_a_folder_is_named_as_such(tmp_path):
    # NumPy reads a file that is no zip archive as a pickle, and used to make
    # a PNG renamed .npz "damaged (... pickled data ...)".
    path = tmp_path / "checkpoint.npz"
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + bytes(100))
    with pytest.raises(
        report.DamagedFileError, match="checkpoint.npz is not a file of save_arrays"
    ):
        report.load_arrays(path)
    with pytest.raises(report.DamagedFileError, match="is a folder; allowed: a file"):
        report.load_arrays(tmp_path)


def test_a_sealed_record_reads_back_whole_and_refuses_any_changed_value(tmp_path):
    from wmr_jax._src import io

    record = {"seed": np.int64(2), "t": (0.1, math.inf), "x": np.float32(0.5), "ok": True}
    path = io.atomic_write_json(tmp_path / "r.json", io.sealed(record))
    read = json.loads(path.read_text())
    # What reads back is the content as JSON holds it, and nothing else.
    assert io.unsealed(read, "r") == {"seed": 2, "t": [0.1, "inf"], "x": 0.5, "ok": True}
    # Key order and layout are not content.
    assert io.unsealed(json.loads(json.dumps(read, indent=3, sort_keys=True)), "r")["seed"] == 2
    for key, other in (("seed", 3), ("t", [0.1, "-inf"]), ("x", 0.5000001), ("ok", 1)):
        with pytest.raises(io.DamagedFileError, match=r"^r was changed after it was written"):
            io.unsealed({**read, key: other}, "r")
    with pytest.raises(io.DamagedFileError, match=r"^r was changed"):
        io.unsealed({**read, "added": 1}, "r")
    with pytest.raises(io.DamagedFileError, match=r"^r was changed"):
        io.unsealed({**read, "t": object()}, "r")  # no JSON at all
    for bad in ({k: v for k, v in read.items() if k != "sha256"}, [read], {**read, "sha256": 1}):
        with pytest.raises(io.DamagedFileError, match=r"^r has no checksum \(.*, or was edited\)$"):
            io.unsealed(bad, "r")
    for bad in (read, [1, 2], None):  # already sealed, or no record
        with pytest.raises(ValueError, match=r"^record = .* allowed: a mapping without"):
            io.sealed(bad)
    with pytest.raises(ValueError, match=r"^record = .* is not allowed .*JSON"):
        io.sealed({"f": print})


def _edit_meta(path, edit):
    """Rewrite ``path`` as a valid .npz with its ``__meta__`` edited and its checksum kept."""
    with np.load(path) as data:
        stored = {name: data[name] for name in data.files}
    meta = json.loads(str(stored["__meta__"]))
    stored["__meta__"] = np.asarray(json.dumps(edit(meta), sort_keys=True))
    np.savez(path, **stored)


def test_edited_meta_data_is_refused_as_edited_values_are(tmp_path):
    # The checksum covers the meta data too: a chunk whose settings were edited
    # would otherwise pass for one of other settings.
    path = tmp_path / "c.npz"
    report.save_arrays(path, {"z": np.arange(5.0)}, {"steps": 150, "dt": 0.033})
    _edit_meta(path, lambda meta: {**meta, "steps": 300})
    with pytest.raises(report.DamagedFileError, match="checksum does not match"):
        report.load_arrays(path)
    # The same text again, key order and all, is the file as written.
    report.save_arrays(path, {"z": np.arange(5.0)}, {"steps": 150, "dt": 0.033})
    _edit_meta(path, lambda meta: meta)
    assert report.load_arrays(path)[1] == {"steps": 150, "dt": 0.033}


def test_a_sweep_chunk_with_edited_meta_data_is_refused(tmp_path):
    import wmr_jax as w

    refs = np.array([[30.0, 20.0, 0.3], [-20.0, 15.0, 1.0]])
    folder = tmp_path / "sweep"
    w.sweep(refs, steps=3, chunk_size=2, out=folder)
    chunks = sorted(folder.rglob("chunk_*.npz"))
    assert chunks
    report.load_arrays(chunks[0])  # as written, it reads
    _edit_meta(chunks[0], lambda meta: {**meta, "edited": True})
    with pytest.raises(report.DamagedFileError, match="checksum does not match"):
        report.load_arrays(chunks[0])
