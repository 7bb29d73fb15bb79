"""Issue 32: a recording keeps its identity (not its blueprint's), several recordings in
one file are never merged, and no write replaces the store's own source."""

import pathlib

import pytest

import chunkstore

IDENTITY = pathlib.Path(__file__).resolve().parents[2] / "testdata" / "rerun-0.41" / "identity"
BLUEPRINT_FIRST = IDENTITY / "blueprint_first.rrd"
OUT_OF_ORDER = IDENTITY / "out_of_order.rrd"


def plot(store):
    """Every row of `/plot/a` on `frame`."""
    return store.range("frame", 0, 9, entity="/plot/a", component="Scalars:scalars")


@pytest.mark.parametrize("lazy", [True, False])
def test_a_blueprint_first_is_not_the_recording(tmp_path, lazy):
    store = chunkstore.open(BLUEPRINT_FIRST, lazy=lazy)
    assert "/plot/a" in store.entities()
    out = tmp_path / "copy.rrd"
    store.write_rrd(out)
    back = chunkstore.open(out)
    assert back.entities() == store.entities()
    assert len(back) == len(store)
    assert plot(back).equals(plot(store))
    # The copy keeps the recording's id: choosing it by that id works.
    assert chunkstore.open(out, recording="blueprint-first-rec").entities() == store.entities()
    with pytest.raises(chunkstore.InvalidInputError, match="blueprint-first-rec"):
        chunkstore.open(out, recording="rec_of_the_blueprint")


def test_write_rrd_renames_the_recording(tmp_path):
    out = tmp_path / "renamed.rrd"
    chunkstore.open(OUT_OF_ORDER).write_rrd(out, recording_id="renamed")
    assert chunkstore.open(out, recording="renamed").entities() == ["/__properties", "/meta", "/plot/a"]


@pytest.mark.parametrize("lazy", [True, False])
def test_two_recordings_in_one_file_are_never_merged(tmp_path, lazy):
    both = tmp_path / "both.rrd"
    both.write_bytes(BLUEPRINT_FIRST.read_bytes() + OUT_OF_ORDER.read_bytes())
    with pytest.raises(chunkstore.InvalidInputError, match='"blueprint-first-rec", "out-of-order-rec"'):
        chunkstore.open(both, lazy=lazy)
    for source, recording in [(BLUEPRINT_FIRST, "blueprint-first-rec"), (OUT_OF_ORDER, "out-of-order-rec")]:
        chosen = chunkstore.open(both, lazy=lazy, recording=recording)
        alone = chunkstore.open(source)
        assert chosen.entities() == alone.entities()
        assert plot(chosen).equals(plot(alone))


@pytest.mark.parametrize("lazy", [True, False])
def test_writes_never_replace_the_source(tmp_path, lazy):
    source = tmp_path / "source.rrd"
    source.write_bytes(OUT_OF_ORDER.read_bytes())
    before = source.read_bytes()
    store = chunkstore.open(source, lazy=lazy)
    with pytest.raises(chunkstore.InvalidInputError, match="overwrite"):
        store.write_rrd(source)
    with pytest.raises(chunkstore.InvalidInputError, match="overwrite"):
        store.write_parquet(source, "frame")
    assert source.read_bytes() == before
    # A link to the source is the source.
    link = tmp_path / "link.rrd"
    link.symlink_to(source)
    with pytest.raises(chunkstore.InvalidInputError, match="overwrite"):
        store.write_rrd(link)
    assert source.read_bytes() == before
    # The store still answers from it.
    assert plot(store).num_rows == 3
