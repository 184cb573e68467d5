"""What the result files mean, each checked against an independent reading.

Files are read back with the standard library and NumPy (``json``,
``zipfile``, ``np.load``, ``os.stat``, PNG headers), never with the code under
test, so that a change to what ``wmr_jax._src.io`` writes is seen.
"""

import json
import math
import os
import stat
import struct
import sys

import numpy as np
import pytest

from wmr_jax._src import io as wio

_JSON_ALLOWED = "allowed: numbers, strings, bools, None, lists and dicts of them (JSON)"


# ---------------------------------------------------------------- atomic writes


def test_a_write_goes_through_a_hidden_temporary_beside_the_file(tmp_path):
    """The temporary lives in the target's folder as ``.<name>.*.tmp`` (what
    ``remove_stale_temporaries`` looks for), so the rename is atomic."""
    target = tmp_path / "a" / "b" / "c.bin"  # two missing folders: made with parents
    seen = []

    def write(f):
        f.write(b"abc")
        seen.extend(p.name for p in target.parent.iterdir())

    wio._write_atomically(target, write)
    assert len(seen) == 1
    assert seen[0].startswith(".c.bin.") and seen[0].endswith(".tmp")
    assert target.read_bytes() == b"abc"
    assert [p.name for p in target.parent.iterdir()] == ["c.bin"]


def test_a_written_file_has_the_usual_permissions_of_the_umask():
    """``0o666 & ~umask``, as ``open(..., "w")`` would give, not mkstemp's 0600."""
    import tempfile

    old = os.umask(0o022)
    try:
        with tempfile.TemporaryDirectory() as d:
            path = wio.atomic_write_bytes(os.path.join(d, "x.bin"), b"1")
            assert stat.S_IMODE(os.stat(path).st_mode) == 0o644
            assert os.umask(0o022) == 0o022  # the process's umask is left as it was
    finally:
        os.umask(old)


def test_a_write_that_fails_midway_keeps_the_old_file_and_its_own_error(tmp_path):
    path = tmp_path / "r.bin"
    path.write_bytes(b"old")

    def write(f):
        f.write(b"half")
        raise OSError("disk full")

    with pytest.raises(OSError, match="^disk full$"):
        wio._write_atomically(path, write)
    assert path.read_bytes() == b"old"
    assert [p.name for p in tmp_path.iterdir()] == ["r.bin"]


@pytest.mark.parametrize("bad", ["", ".", 3, None])
def test_a_write_refuses_what_is_no_file_path(tmp_path, bad):
    with pytest.raises(ValueError, match=r"^path = .* is not allowed; allowed: a file path$"):
        wio.atomic_write_bytes(bad, b"x")


def test_a_write_refuses_a_folder_naming_it(tmp_path):
    with pytest.raises(ValueError, match=rf"^path = {str(tmp_path)!r} is a folder"):
        wio.atomic_write_bytes(tmp_path, b"x")


def test_bytes_and_text_writers_refuse_the_other_kind_naming_the_type(tmp_path):
    with pytest.raises(ValueError, match=r"^data is a str; allowed: bytes"):
        wio.atomic_write_bytes(tmp_path / "a", "text")
    with pytest.raises(ValueError, match=r"^text = b'x' is not allowed; allowed: a str$"):
        wio.atomic_write_text(tmp_path / "a", b"x")
    assert list(tmp_path.iterdir()) == []


def test_text_is_written_as_utf8(tmp_path):
    path = wio.atomic_write_text(tmp_path / "t.txt", "θ = 1°")
    assert path.read_bytes() == "θ = 1°".encode()


# ---------------------------------------------------------------- JSON


def test_json_file_is_indented_by_two_in_the_given_key_order_with_a_newline(tmp_path):
    obj = {"b": 1, "a": [1.5, math.inf], "c": {"z": -math.inf, "y": math.nan}}
    path = wio.atomic_write_json(tmp_path / "o.json", obj)
    expected = {"b": 1, "a": [1.5, "inf"], "c": {"z": "-inf", "y": "nan"}}
    assert path.read_text() == json.dumps(expected, indent=2) + "\n"


def test_json_of_arrays_is_their_list_of_numbers():
    """NumPy arrays and scalars are written as the numbers they hold."""
    text = wio.json_text({"x": np.array([[0.5, np.inf], [-np.inf, 2.0]]), "n": np.int64(3)}, "v")
    assert json.loads(text) == {"x": [[0.5, "inf"], ["-inf", 2.0]], "n": 3}
    assert wio.json_text(np.float32(0.25), "v") == "0.25"


def test_json_passes_its_options_through():
    assert wio.json_text({"b": 1, "a": 2}, "v", sort_keys=True) == '{"a": 2, "b": 1}'


def test_json_refuses_keys_that_collide_as_names_naming_both():
    collide = r"\(keys '1', 1 collide as JSON names \(str of each\)\); allowed"
    with pytest.raises(ValueError, match=collide):
        wio.json_text({1: "a", "1": "b"}, "v")


def test_json_refuses_a_value_naming_it_and_what_is_allowed(tmp_path):
    with pytest.raises(ValueError) as err:
        wio.atomic_write_json(tmp_path / "o.json", {"f": {1, 2}})
    msg = str(err.value)
    assert msg.startswith("obj = {'f': {1, 2}} is not allowed (")
    assert msg.endswith("); " + _JSON_ALLOWED)
    assert list(tmp_path.iterdir()) == []  # nothing written


def test_json_refuses_a_value_that_contains_itself():
    loop = []
    loop.append(loop)
    with pytest.raises(ValueError) as err:
        wio.json_text(loop, "meta")
    assert str(err.value) == (
        "meta is not allowed: it contains itself, or nests too deeply for JSON; " + _JSON_ALLOWED
    )


def test_json_object_once_refuses_a_repeated_key_and_keeps_the_rest():
    assert json.loads('{"a": 1, "b": 2}', object_pairs_hook=wio.json_object_once) == {
        "a": 1,
        "b": 2,
    }
    with pytest.raises(ValueError, match=r"^the key 'a' is given twice$"):
        json.loads('{"a": 1, "b": 2, "a": 3}', object_pairs_hook=wio.json_object_once)


# ---------------------------------------------------------------- checked array files


def test_saved_meta_is_stored_as_json_with_sorted_keys(tmp_path):
    """The same meta in another order gives the same stored text (and checksum)."""
    path = wio.save_arrays(tmp_path / "m.npz", {"x": np.arange(2)}, {"b": 1, "a": math.inf})
    with np.load(path, allow_pickle=False) as data:
        assert str(data["__meta__"]) == '{"a": "inf", "b": 1}'
        assert sorted(data.files) == ["__meta__", "__sha256__", "x"]


def test_strings_dates_and_bools_round_trip(tmp_path):
    arrays = {
        "s": np.array(["ab", "c"]),
        "b": np.array([b"x", b"yz"]),
        "d": np.array(["2024-01-02"], dtype="datetime64[D]"),
        "t": np.array([3], dtype="timedelta64[s]"),
        "q": np.array([True, False]),
        "c": np.array([1 + 2j]),
    }
    wio.save_arrays(tmp_path / "s.npz", arrays, {})
    back, meta = wio.load_arrays(tmp_path / "s.npz")
    assert meta == {}
    for name, arr in arrays.items():
        assert back[name].dtype == arr.dtype
        np.testing.assert_array_equal(back[name], arr)


@pytest.mark.parametrize("name", ["__meta__", "__sha256__", 7])
def test_reserved_or_non_str_array_names_are_refused(tmp_path, name):
    with pytest.raises(ValueError, match=r"^arrays name = .* is not allowed; allowed: a str other"):
        wio.save_arrays(tmp_path / "a.npz", {name: np.zeros(1)}, {})
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("value", [[[1, 2], [3]], None, {"a": 1}])
def test_arrays_that_need_pickle_are_refused_before_writing(tmp_path, value):
    with pytest.raises(ValueError) as err:
        wio.save_arrays(tmp_path / "a.npz", {"x": value}, {})
    assert str(err.value).startswith("arrays['x'] = ")
    assert str(err.value).endswith(
        "allowed: an array of numbers, bools or strings (not objects: None, dicts, ragged lists)"
    )
    assert list(tmp_path.iterdir()) == []


def test_arrays_not_a_mapping_are_refused(tmp_path):
    with pytest.raises(ValueError, match=r"^arrays = \[1\] is not allowed; allowed: a mapping"):
        wio.save_arrays(tmp_path / "a.npz", [1], {})


def test_meta_json_cannot_store_is_refused_naming_meta(tmp_path):
    with pytest.raises(ValueError, match=r"^meta = \{'k': <object"):
        wio.save_arrays(tmp_path / "a.npz", {}, {"k": object()})
    assert list(tmp_path.iterdir()) == []


def test_a_file_with_pickled_objects_is_refused_without_unpickling(tmp_path):
    """Loading never runs pickle: a file whose array would run code on unpickling
    is refused, and the code does not run."""
    flag = tmp_path / "ran"

    class Trap:
        def __reduce__(self):
            return (os.mkdir, (str(flag),))

    path = tmp_path / "p.npz"
    np.savez(path, x=np.array([Trap()], dtype=object), __meta__="{}", __sha256__="0")
    with pytest.raises(wio.DamagedFileError, match="is damaged"):
        wio.load_arrays(path)
    assert not flag.exists()


def test_a_damaged_archive_is_named_with_the_error_type(tmp_path):
    path = tmp_path / "z.npz"
    path.write_bytes(b"PK\x03\x04" + b"\0" * 40)
    with pytest.raises(wio.DamagedFileError, match=r"is damaged \(BadZipFile: "):
        wio.load_arrays(path)


def test_a_file_of_another_kind_is_named_as_such(tmp_path):
    path = tmp_path / "n.npz"
    path.write_bytes(b"\x93NUMPY")
    with pytest.raises(wio.DamagedFileError) as err:
        wio.load_arrays(path)
    assert str(err.value) == (
        f"{path} is not a file of save_arrays: it is no .npz archive (another kind "
        "of file, or one damaged at its start)"
    )


def test_remove_stale_temporaries_removes_only_the_hidden_tmp_files(tmp_path):
    (tmp_path / ".a.json.x1.tmp").write_text("")
    (tmp_path / "b.tmp").write_text("")  # not hidden: not ours
    (tmp_path / ".c.tmp.d").mkdir()
    removed = wio.remove_stale_temporaries(tmp_path)
    assert [p.name for p in removed] == [".a.json.x1.tmp"]
    assert sorted(p.name for p in tmp_path.iterdir()) == [".c.tmp.d", "b.tmp"]
    assert wio.remove_stale_temporaries(tmp_path / "none") == []


# ---------------------------------------------------------------- figures


@pytest.fixture
def fig():
    import matplotlib

    matplotlib.use("Agg")
    from matplotlib.figure import Figure

    f = Figure(figsize=(2, 1))
    f.add_subplot().plot([0, 1], [0, 1])
    return f


def test_a_figure_is_rendered_in_the_format_of_its_suffix_at_the_given_dpi(tmp_path, fig):
    path = wio.save_figure(fig, tmp_path / "f.PNG", dpi=10)
    data = path.read_bytes()
    assert data[:8] == b"\x89PNG\r\n\x1a\n"
    # IHDR: width and height are the figure's inches times dpi (2 x 1 in at 10 dpi).
    assert struct.unpack(">II", data[16:24]) == (20, 10)
    assert wio.save_figure(fig, str(tmp_path / "f.pdf")).read_bytes()[:5] == b"%PDF-"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f.PNG", "f.pdf"]


@pytest.mark.parametrize("name", ["f.xyz", "f.Xpng", "png"])
def test_a_figure_path_without_an_image_suffix_is_refused_listing_the_formats(tmp_path, fig, name):
    """The format is the whole suffix after its one dot: ``.Xpng`` is not ``.png``."""
    with pytest.raises(ValueError) as err:
        wio.save_figure(fig, tmp_path / name)
    msg = str(err.value)
    assert msg.startswith(f"path = {str(tmp_path / name)!r} is not allowed; allowed: a path ")
    formats = msg.split("ending in ")[1].split(", ")
    assert formats == sorted(formats) and {".png", ".pdf", ".svg"} <= set(formats)
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("bad", ["", None, 3])
def test_a_figure_path_that_is_no_file_name_is_refused(fig, bad):
    with pytest.raises(ValueError, match=r"^path = .* is not allowed; allowed: a file name"):
        wio.save_figure(fig, bad)


def test_save_figure_refuses_what_is_no_figure(tmp_path):
    with pytest.raises(ValueError, match=r"^fig is a int; allowed: a matplotlib Figure$"):
        wio.save_figure(3, tmp_path / "f.png")


# ---------------------------------------------------------------- writable paths


def test_writable_path_creates_nothing_and_returns_the_path(tmp_path):
    want = tmp_path / "a" / "b" / "c.json"
    assert wio.writable_path("out", str(want), folder=False) == want
    assert wio.writable_path("out", tmp_path / "d", folder=True) == tmp_path / "d"
    assert wio.writable_path("out", tmp_path, folder=True) == tmp_path
    (tmp_path / "e.json").write_text("")
    assert wio.writable_path("out", tmp_path / "e.json", folder=False) == tmp_path / "e.json"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["e.json"]


@pytest.mark.parametrize("folder, want", [(True, "a folder name"), (False, "a file name")])
@pytest.mark.parametrize("bad", ["", None, 3])
def test_writable_path_refuses_no_name(bad, folder, want):
    with pytest.raises(ValueError) as err:
        wio.writable_path("--out ''", bad, folder=folder)
    assert str(err.value) == f"--out '' is not allowed; allowed: {want}"


def test_writable_path_refuses_the_wrong_kind_naming_both(tmp_path):
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError) as err:
        wio.writable_path("out = 'f'", tmp_path / "f", folder=True)
    assert str(err.value) == "out = 'f' is not allowed; allowed: a folder (it is a file)"
    with pytest.raises(ValueError) as err:
        wio.writable_path("out = 'd'", tmp_path, folder=False)
    assert str(err.value) == "out = 'd' is not allowed; allowed: a file name (it is a folder)"


@pytest.mark.parametrize("folder", [True, False])
def test_writable_path_refuses_a_path_through_a_file(tmp_path, folder):
    (tmp_path / "f").write_text("")
    with pytest.raises(ValueError) as err:
        wio.writable_path("out", tmp_path / "f" / "g" / "h", folder=folder)
    assert str(err.value) == f"out is not allowed; {str(tmp_path / 'f')!r} is a file, not a folder"


@pytest.mark.skipif(not sys.platform.startswith("linux"), reason="needs /sys")
def test_writable_path_refuses_a_place_no_file_can_be_made():
    """/sys takes no new files, even from root; the message gives the system's reason."""
    import tempfile

    with pytest.raises(OSError) as os_err:
        tempfile.TemporaryFile(dir="/sys")
    with pytest.raises(ValueError) as err:
        wio.writable_path("out", "/sys/x/y.json", folder=False)
    assert str(err.value) == (
        f"out is not allowed; allowed: a place this process can write ({os_err.value.strerror})"
    )
