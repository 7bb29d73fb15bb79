//! The schema cache and the own batch decoder decode exactly as arrow-ipc does, hit or
//! miss, hostile or not.

#![allow(
    clippy::unwrap_used,
    clippy::expect_used,
    reason = "tests fail loudly on unexpected values"
)]

use std::collections::HashMap;
use std::sync::Arc;

use arrow_array::{ArrayRef, Float64Array, Int64Array, RecordBatch};
use arrow_buffer::Buffer;
use arrow_schema::{DataType, Field, Schema};

use super::schema_cache;
use super::schema_layout::SchemaLayout;
use super::{read_batches, read_stream_batches_zero_copy, without_schema_cache};

/// An IPC stream of one two-column batch whose schema carries `metadata`; `column` names
/// the second column.
fn stream(metadata: &[(&str, &str)], column: &str) -> Vec<u8> {
    let metadata: HashMap<String, String> = metadata
        .iter()
        .map(|(k, v)| ((*k).to_owned(), (*v).to_owned()))
        .collect();
    let field_metadata = HashMap::from([("rerun:kind".to_owned(), "data".to_owned())]);
    let schema = Arc::new(Schema::new_with_metadata(
        vec![
            Field::new("frame", DataType::Int64, false),
            Field::new(column, DataType::Float64, true).with_metadata(field_metadata),
        ],
        metadata,
    ));
    let batch = RecordBatch::try_new(
        Arc::clone(&schema),
        vec![
            Arc::new(Int64Array::from(vec![1, 2, 3])) as ArrayRef,
            Arc::new(Float64Array::from(vec![Some(0.5), None, Some(2.5)])),
        ],
    )
    .unwrap();
    let mut out = Vec::new();
    let mut writer = arrow_ipc::writer::StreamWriter::try_new(&mut out, &schema).unwrap();
    writer.write(&batch).unwrap();
    writer.finish().unwrap();
    drop(writer);
    out
}

fn chunk_stream(id: &str) -> Vec<u8> {
    stream(
        &[("rerun:id", id), ("rerun:entity_path", "/robot/arm")],
        "scalar",
    )
}

/// Where the first message's metadata (the schema) lies: after the continuation marker and
/// the length.
fn schema_message(stream: &[u8]) -> std::ops::Range<usize> {
    let len = i32::from_le_bytes(stream[4..8].try_into().unwrap());
    8..8 + usize::try_from(len).unwrap()
}

/// Decoding through the cache gives what a decode without it gives, and what arrow-ipc's
/// own reader gives: equal batches (schema and metadata included), or all an error.
fn decodes_like_arrow(stream: &[u8]) -> Option<Vec<RecordBatch>> {
    let cached = read_stream_batches_zero_copy(Buffer::from(stream.to_vec()));
    let uncached =
        without_schema_cache(|| read_stream_batches_zero_copy(Buffer::from(stream.to_vec())));
    let arrow = read_batches(stream);
    match (cached, uncached, arrow) {
        (Ok(cached), Ok(uncached), Ok(arrow)) => {
            assert_eq!(cached, uncached);
            assert_eq!(cached, arrow);
            Some(cached)
        }
        (Err(_), Err(_), Err(_)) => None,
        (cached, uncached, arrow) => panic!(
            "cached, uncached and arrow-ipc disagree: {:?}, {:?}, {:?}",
            cached.map(|b| b.len()),
            uncached.map(|b| b.len()),
            arrow.map(|b| b.len())
        ),
    }
}

fn id(i: usize) -> String {
    format!("{i:032x}")
}

#[test]
fn a_repeated_schema_is_parsed_twice_then_reused_with_its_own_metadata() {
    schema_cache::clear();
    for i in 0..5 {
        let batches = decodes_like_arrow(&chunk_stream(&id(i))).unwrap();
        assert_eq!(batches[0].schema().metadata()["rerun:id"], id(i));
    }
    // The first was parsed and its length remembered, the second parsed and kept; the
    // other three came from the cache.
    assert_eq!(schema_cache::counts(), (3, 1));

    // Another column name of the same length is another layout, of a length seen: kept at
    // once.
    let renamed = |i: usize| {
        stream(
            &[("rerun:id", &id(i)), ("rerun:entity_path", "/robot/arm")],
            "scalor",
        )
    };
    decodes_like_arrow(&renamed(9)).unwrap();
    assert_eq!(schema_cache::counts(), (3, 2));
    decodes_like_arrow(&renamed(10)).unwrap();
    assert_eq!(schema_cache::counts(), (4, 2));

    // A value of another length is another layout too, kept from its second message on.
    decodes_like_arrow(&chunk_stream("short")).unwrap();
    assert_eq!(schema_cache::counts(), (4, 2));
    decodes_like_arrow(&chunk_stream("shirt")).unwrap();
    assert_eq!(schema_cache::counts(), (4, 3));
    decodes_like_arrow(&chunk_stream("shore")).unwrap();
    assert_eq!(schema_cache::counts(), (5, 3));
}

#[test]
fn the_proof_names_every_metadata_value_as_a_slot() {
    let bytes = chunk_stream(&id(7));
    let message = &bytes[schema_message(&bytes)];
    let layout = SchemaLayout::prove(message).expect("arrow-rs's own layout is provable");
    let mut values: Vec<&str> = layout
        .slots
        .iter()
        .map(|slot| std::str::from_utf8(&message[slot.clone()]).unwrap())
        .collect();
    values.sort_unstable();
    assert_eq!(values, ["/robot/arm", id(7).as_str()]);
    // A record batch message has no layout.
    let batch_at = schema_message(&bytes).end;
    let rest = &bytes[batch_at..];
    let len = i32::from_le_bytes(rest[4..8].try_into().unwrap());
    assert!(SchemaLayout::prove(&rest[8..8 + usize::try_from(len).unwrap()]).is_none());
}

/// Rewrites the stream so that the first metadata entry's key is its own value's string:
/// a valid flatbuffer in which the value's bytes are read twice.
fn alias_first_key_to_its_value(stream: &mut [u8]) {
    let message = schema_message(stream);
    let buf = &stream[message.clone()];
    let u32_at = |at: usize| u32::from_le_bytes(buf[at..at + 4].try_into().unwrap()) as usize;
    let u16_at = |at: usize| usize::from(u16::from_le_bytes(buf[at..at + 2].try_into().unwrap()));
    let vtable = |table: usize| {
        let soffset = i32::from_le_bytes(buf[table..table + 4].try_into().unwrap());
        usize::try_from(i64::try_from(table).unwrap() - i64::from(soffset)).unwrap()
    };
    let field = |table: usize, voffset: usize| table + u16_at(vtable(table) + voffset);
    let follow = |at: usize| at + u32_at(at);
    let root = u32_at(0);
    let schema = follow(field(root, 8));
    let metadata = follow(field(schema, 8));
    let entry = follow(metadata + 4);
    let key_field = field(entry, 4);
    let value = follow(field(entry, 6));
    assert!(
        value > key_field,
        "arrow-rs writes strings before their table"
    );
    let offset = u32::try_from(value - key_field).unwrap().to_le_bytes();
    let at = message.start + key_field;
    stream[at..at + 4].copy_from_slice(&offset);
}

#[test]
fn a_value_that_something_else_reads_is_never_a_slot() {
    schema_cache::clear();
    let mut first = stream(&[("rerun:id", &id(1))], "scalar");
    alias_first_key_to_its_value(&mut first);
    let message = schema_message(&first);
    assert!(SchemaLayout::prove(&first[message]).is_none());
    let batches = decodes_like_arrow(&first).unwrap();
    // The key is the value now: the aliasing is real.
    assert_eq!(batches[0].schema().metadata()[&id(1)], id(1));

    // Changing the value changes the key too, which a cache keyed on the other bytes would
    // have missed.
    let mut second = stream(&[("rerun:id", &id(2))], "scalar");
    alias_first_key_to_its_value(&mut second);
    let batches = decodes_like_arrow(&second).unwrap();
    assert_eq!(batches[0].schema().metadata()[&id(2)], id(2));
    assert_eq!(schema_cache::counts(), (0, 0));
}

#[test]
fn a_value_that_is_not_utf8_is_refused_as_the_verifier_refuses_it() {
    schema_cache::clear();
    decodes_like_arrow(&chunk_stream(&id(1))).unwrap();
    decodes_like_arrow(&chunk_stream(&id(2))).unwrap();
    assert_eq!(schema_cache::counts(), (0, 1));
    let mut bad = chunk_stream(&id(3));
    let message = schema_message(&bad);
    let layout = SchemaLayout::prove(&bad[message.clone()]).unwrap();
    let at = message.start + layout.slots[0].start;
    bad[at] = 0xff;
    assert!(decodes_like_arrow(&bad).is_none());
    assert_eq!(schema_cache::counts(), (0, 1));
}

#[test]
fn the_cache_keeps_a_bounded_number_of_layouts() {
    schema_cache::clear();
    for i in 0..200 {
        decodes_like_arrow(&stream(&[("rerun:id", &id(i))], &format!("c{i:04}"))).unwrap();
    }
    let (hits, kept) = schema_cache::counts();
    assert_eq!(hits, 0);
    assert!((1..=64).contains(&kept), "{kept} layouts kept");
    // The most recent layouts are still there.
    decodes_like_arrow(&stream(&[("rerun:id", &id(1000))], "c0199")).unwrap();
    assert_eq!(schema_cache::counts().0, 1);
}

#[cfg(feature = "rrd")]
#[test]
fn a_recording_written_by_rerun_reuses_its_schemas() {
    let path = concat!(
        env!("CARGO_MANIFEST_DIR"),
        "/../shared/testdata/rerun-0.41/a_robot/a_robot.rrd"
    );
    let bytes = std::fs::read(path).unwrap();
    schema_cache::clear();
    let built = super::batch_decoder::batches_built();
    let contents = crate::rrd::read_rrd(Buffer::from_vec(bytes), false).unwrap();
    // Every chunk of Rerun's recording (and of its blueprint, not among the chunks
    // returned) is a batch the own decoder builds.
    assert!(super::batch_decoder::batches_built() - built >= contents.chunks.len() as u64);
    let (hits, kept) = schema_cache::counts();
    assert!(
        hits > 0,
        "no schema reused among {} chunks",
        contents.chunks.len()
    );
    assert!(kept > 0);
    // tests/core/rrd.rs checks every chunk against Rerun's own chunk files.
}

/// A one-batch IPC stream of `batch`.
pub(super) fn stream_of(batch: &RecordBatch) -> Vec<u8> {
    let mut out = Vec::new();
    let mut writer = arrow_ipc::writer::StreamWriter::try_new(&mut out, &batch.schema()).unwrap();
    writer.write(batch).unwrap();
    writer.finish().unwrap();
    drop(writer);
    out
}

/// Decodes `stream` with the own batch decoder, which must build its batch (or not, per
/// `built`), and checks the answer against arrow-ipc's alone.
fn decode_own(stream: &[u8], built: bool) -> Vec<RecordBatch> {
    let before = super::batch_decoder::batches_built();
    let own = read_stream_batches_zero_copy(Buffer::from(stream.to_vec())).unwrap();
    assert_eq!(super::batch_decoder::batches_built() > before, built);
    let reference = super::without_own_batch_decoder(|| {
        read_stream_batches_zero_copy(Buffer::from(stream.to_vec())).unwrap()
    });
    assert_eq!(own, reference);
    own
}

/// Every array type chunks are made of, nulls at every level, built by the own decoder;
/// a type it does not build goes to arrow-ipc, with the same answer.
#[test]
fn the_own_batch_decoder_builds_what_chunks_hold_and_hands_over_the_rest() {
    use arrow_array::builder::{
        BooleanBuilder, FixedSizeListBuilder, Float32Builder, ListBuilder, StringBuilder,
    };
    use arrow_array::{
        Array, BinaryArray, FixedSizeBinaryArray, Int32Array, LargeStringArray, StructArray,
        UInt8Array,
    };
    let ids = FixedSizeBinaryArray::try_from_iter((0u8..4).map(|i| [i; 16])).unwrap();
    let mut points = ListBuilder::new(FixedSizeListBuilder::new(Float32Builder::new(), 3));
    for row in 0u8..4 {
        if row == 2 {
            points.append(false);
            continue;
        }
        for k in 0..row {
            points
                .values()
                .values()
                .append_slice(&[f32::from(k), 1.0, 2.0]);
            points.values().append(true);
        }
        points.append(true);
    }
    let mut texts = ListBuilder::new(StringBuilder::new());
    texts.append_value([Some("a"), None, Some("é")]);
    texts.append_null();
    texts.append_value([Some("")]);
    texts.append_value([None::<&str>]);
    let mut flags = ListBuilder::new(BooleanBuilder::new());
    flags.append_value([Some(true), None]);
    flags.append_value([Some(false)]);
    flags.append_null();
    flags.append_value([]);
    let pairs = StructArray::from(vec![
        (
            Arc::new(Field::new("a", DataType::Int32, true)),
            Arc::new(Int32Array::from(vec![Some(1), None, Some(3), Some(4)])) as ArrayRef,
        ),
        (
            Arc::new(Field::new("b", DataType::Binary, false)),
            Arc::new(BinaryArray::from(vec![&b"x"[..], b"", b"yz", b"w"])) as ArrayRef,
        ),
    ]);
    let columns: Vec<(&str, ArrayRef)> = vec![
        ("row_id", Arc::new(ids)),
        (
            "frame",
            Arc::new(Int64Array::from(vec![Some(1), Some(2), None, Some(4)])),
        ),
        ("points", Arc::new(points.finish())),
        ("texts", Arc::new(texts.finish())),
        ("flags", Arc::new(flags.finish())),
        ("pairs", Arc::new(pairs)),
        ("bytes", Arc::new(UInt8Array::from(vec![1, 2, 3, 255]))),
    ];
    let batch = RecordBatch::try_from_iter(columns.clone()).unwrap();
    assert_eq!(
        decode_own(&stream_of(&batch), true),
        std::slice::from_ref(&batch)
    );
    // A slice (its offsets start past 0, its validity past bit 0) decodes the same.
    let sliced = batch.slice(1, 3);
    assert_eq!(decode_own(&stream_of(&sliced), true), [sliced]);
    // A type the decoder leaves to arrow-ipc.
    let mut other = columns;
    other.push((
        "large",
        Arc::new(LargeStringArray::from(vec!["a", "b", "c", "d"])),
    ));
    let batch = RecordBatch::try_from_iter(other).unwrap();
    assert_eq!(
        decode_own(&stream_of(&batch), false),
        std::slice::from_ref(&batch)
    );
    assert_eq!(batch.num_rows(), batch.column(0).len());
}

/// A chunk's transport batch with `extra` schema metadata entries.
fn chunk_batch(chunk_id: crate::ChunkId, extra: &[(&str, &str)]) -> RecordBatch {
    let value = Arc::new(Float64Array::from(vec![1.5])) as ArrayRef;
    let chunk = crate::ChunkBuilder::new(chunk_id, crate::EntityPath::parse("/robot/arm").unwrap())
        .with_row(
            crate::RowId::new(),
            [(crate::Timeline::sequence("frame"), 7)],
            [("scalar", value)],
        )
        .build()
        .unwrap();
    let batch = chunk.to_record_batch().unwrap();
    let mut metadata = batch.schema().metadata().clone();
    for (key, value) in extra {
        metadata.insert((*key).to_owned(), (*value).to_owned());
    }
    let schema = Arc::new(Schema::new_with_metadata(
        batch.schema().fields().clone(),
        metadata,
    ));
    batch.with_schema(schema).unwrap()
}

/// Chunks decoded straight from a stream, from a cached schema without a `Schema` or a
/// `RecordBatch`, are those made of its batches decoded in full: with the message's own
/// id, with what metadata is kept, and where a key repeats, with the value
/// `fb_to_schema`'s map keeps (the last in message order).
#[test]
fn chunks_straight_from_a_stream_are_those_of_its_batches() {
    use super::read_stream_chunks_zero_copy;
    schema_cache::clear();
    for repeat_key in [false, true] {
        // One message per layout (a map's entries come out in an order of its own), and
        // each chunk's id written into a copy of it.
        let first_id = crate::ChunkId::new().to_string();
        let decoy = crate::ChunkId::new().to_string();
        let mut template = stream_of(&chunk_batch(
            first_id.parse().unwrap(),
            &[("rerun:iX", &decoy), ("sorbet:version", "0.1")],
        ));
        if repeat_key {
            let at = template
                .windows(8)
                .position(|w| w == b"rerun:iX")
                .expect("the key is in the message");
            template[at..at + 8].copy_from_slice(b"rerun:id");
        }
        let id_at = template
            .windows(first_id.len())
            .position(|w| w == first_id.as_bytes())
            .expect("the id is in the message");
        for _ in 0..4 {
            let chunk_id = crate::ChunkId::new().to_string();
            let mut bytes = template.clone();
            bytes[id_at..id_at + chunk_id.len()].copy_from_slice(chunk_id.as_bytes());
            let direct = read_stream_chunks_zero_copy(&Buffer::from(bytes.clone())).unwrap();
            let batches = without_schema_cache(|| {
                read_stream_batches_zero_copy(Buffer::from(bytes.clone())).unwrap()
            });
            let made = crate::Chunk::from_record_batch(&batches[0]).unwrap();
            assert_eq!(direct.len(), 1);
            assert_eq!(
                direct[0].to_record_batch().unwrap(),
                made.to_record_batch().unwrap()
            );
            let expected_id = batches[0].schema_ref().metadata()["rerun:id"].clone();
            assert_eq!(direct[0].id().to_string(), expected_id);
            if !repeat_key {
                assert_eq!(expected_id, chunk_id);
            }
        }
    }
    // The first layout was parsed twice (then kept) and came from the cache twice; the
    // second, of a length seen, was kept at once and came from the cache three times.
    assert_eq!(schema_cache::counts(), (5, 2));
}
