"""Rerun's own answers on the robot recording (testdata/rerun-0.41/a_robot/oracle),
reproduced from Python: the same tables the Rust oracle test checks."""

import json

import pyarrow as pa

from conftest import ORACLE, TIMELINES, read_arrow


def _is_index(field: pa.Field) -> bool:
    return (field.metadata or {}).get(b"rerun:kind") == b"index"


def assert_same_table(ours: pa.Table, theirs: pa.Table, index: str, what: str) -> None:
    """Same columns in the same order, the index column equal, every data column equal
    (Rerun fills the *other* index columns with maxima: not compared, per its README)."""
    assert ours.column_names == theirs.column_names, what
    assert ours.num_rows == theirs.num_rows, what
    for i, field in enumerate(theirs.schema):
        if _is_index(field) and field.name != index:
            continue
        mine = ours.schema.field(i)
        assert mine.type == field.type, f"{what}: type of {field.name}"
        for key in (b"rerun:entity_path", b"rerun:component", b"rerun:kind", b"rerun:is_static"):
            assert (mine.metadata or {}).get(key) == (field.metadata or {}).get(key), (
                f"{what}: {key} of {field.name}"
            )
        assert ours.column(i).combine_chunks().equals(theirs.column(i).combine_chunks()), (
            f"{what}: column {field.name}"
        )


def test_sampled_tables_equal_rerun_latest_at(robot):
    for timeline in TIMELINES:
        (theirs,) = read_arrow(ORACLE / f"latest_at__{timeline}.arrow")
        theirs = pa.Table.from_batches([theirs])
        probes = theirs.column(timeline).cast(pa.int64()).to_pylist()
        for fill in (False, True):
            reader = robot.dataframe(timeline, index_values=probes, fill_latest_at=fill, batch_rows=7)
            assert_same_table(reader.read_all(), theirs, timeline, f"latest_at {timeline}")


def test_range_tables_equal_rerun_ranges(robot):
    for timeline in TIMELINES:
        theirs_all = read_arrow(ORACLE / f"range__{timeline}.arrow")
        ranges = json.loads((ORACLE / f"range__{timeline}.json").read_text())["ranges"]
        assert len(ranges) == len(theirs_all)
        for spec, theirs in zip(ranges, theirs_all):
            ours = robot.dataframe(timeline, range=(spec["lo"], spec["hi"])).read_all()
            assert_same_table(
                ours, pa.Table.from_batches([theirs]), timeline, f"range {timeline} {spec['lo']}..{spec['hi']}"
            )


def test_static_columns_equal_rerun_static_table(robot):
    (theirs,) = read_arrow(ORACLE / "static.arrow")
    # `/**` leaves `/__properties` out unless named, as Rerun's filters do.
    ours = robot.dataframe("frame_id", contents=["/**", "/__properties/**"], index_values=[0]).read_all()
    matched = 0
    for field, column in zip(theirs.schema, theirs.columns):
        if _is_index(field):
            continue
        meta = field.metadata
        name = f"{meta[b'rerun:entity_path'].decode()}:{meta[b'rerun:component'].decode()}"
        assert ours.column(name).combine_chunks().equals(column), name
        matched += 1
    assert matched == 2


def test_latest_at_equals_rerun_cell_by_cell(robot):
    """`Store.latest_at` (not the dataframe) gives each oracle cell, component by component."""
    (theirs,) = read_arrow(ORACLE / "latest_at__frame_id.arrow")
    probes = theirs.column(theirs.schema.get_field_index("frame_id")).to_pylist()
    checked = 0
    for i, field in enumerate(theirs.schema):
        if _is_index(field):
            continue
        entity = field.metadata[b"rerun:entity_path"].decode()
        component = field.metadata[b"rerun:component"].decode()
        column = theirs.column(i)
        for row, t in enumerate(probes):
            ours = robot.latest_at("frame_id", t, entity, components=[component])
            expected = column.slice(row, 1)
            if expected.null_count == 1:
                assert ours.num_rows == 0 or ours.column(component).null_count == 1, (entity, component, t)
            else:
                assert ours.num_rows == 1
                assert ours.column(component).equals(expected), (entity, component, t)
                checked += 1
    assert checked > 300
