//! An IPC stream's record batches, decoded zero-copy, as parts a chunk is made of.
//!
//! Each message's flatbuffer is verified once (arrow-ipc's `StreamDecoder` would verify
//! it again, a third of a small chunk's decoding) and decoded with our batch decoder or
//! arrow-ipc's own schema, dictionary and batch readers. A schema message this thread
//! provably decoded before (`schema_cache`) is neither verified nor parsed again, and its
//! batch is not put into a `RecordBatch` with a `Schema` of its own: a chunk reads two of
//! the schema's metadata values and its fields, and a one-row chunk spent a tenth of its
//! decoding building that schema's metadata map and dropping it (`docs/PERFORMANCE.md`).

use arrow_array::{RecordBatch, RecordBatchOptions};
use arrow_buffer::Buffer;
use arrow_schema::{ArrowError, Fields, SchemaRef};
use smallvec::SmallVec;

use super::batch_decoder::Columns;
use super::batch_message::BatchHeader;
use super::schema_cache::{self, CachedSchema};
use super::{IpcError, batch_decoder, body_range, next_frame, verify_message};
use crate::{Chunk, ChunkError};

/// One record batch of a stream: its schema and its columns, checked as a `RecordBatch`
/// checks them.
pub(crate) struct StreamBatch<'a> {
    schema: BatchSchema<'a>,
    columns: Columns,
    rows: usize,
}

/// The schema a batch was decoded against.
#[derive(Clone)]
enum BatchSchema<'a> {
    /// Parsed from its message.
    Parsed(SchemaRef),
    /// Found in this thread's cache: a kept schema's fields, this message's metadata.
    Cached(CachedSchema<'a>),
}

impl BatchSchema<'_> {
    fn fields(&self) -> &Fields {
        match self {
            Self::Parsed(parsed) => parsed.fields(),
            Self::Cached(cached) => cached.template.fields(),
        }
    }

    /// The schema in full, as arrow-ipc's readers take it.
    fn full(&self) -> SchemaRef {
        match self {
            Self::Parsed(parsed) => std::sync::Arc::clone(parsed),
            Self::Cached(cached) => cached.to_schema(),
        }
    }
}

impl StreamBatch<'_> {
    /// The batch as a `RecordBatch`.
    pub(crate) fn into_record_batch(self) -> Result<RecordBatch, IpcError> {
        let schema = self.schema.full();
        let options = RecordBatchOptions::new().with_row_count(Some(self.rows));
        RecordBatch::try_new_with_options(schema, self.columns.into_vec(), &options)
            .map_err(IpcError::Ipc)
    }

    /// The chunk the batch holds in the transport layout, as
    /// [`Chunk::from_record_batch`] decodes it from [`StreamBatch::into_record_batch`].
    pub(crate) fn into_chunk(self) -> Result<Chunk, ChunkError> {
        match &self.schema {
            BatchSchema::Parsed(schema) => Chunk::from_transport_parts(
                schema.fields(),
                &crate::chunk::str_entries(schema.metadata()),
                self.columns,
            ),
            BatchSchema::Cached(cached) => Chunk::from_transport_parts(
                cached.template.fields(),
                &cached.metadata(),
                self.columns,
            ),
        }
    }
}

/// The batches of a stream: one in a chunk's payload, so kept inline.
pub(crate) type StreamBatches<'a> = SmallVec<[StreamBatch<'a>; 1]>;

/// Decodes the batches of an IPC stream whose framing is checked as in
/// `for_each_stream_message`, zero-copy from `buffer`.
pub(crate) fn decode_stream(buffer: &Buffer) -> Result<StreamBatches<'_>, IpcError> {
    use arrow_ipc::MessageHeader;
    let unexpected = |reason: &str| IpcError::Ipc(ArrowError::IpcError(reason.to_owned()));
    let bytes = buffer.as_slice();
    let mut schema: Option<BatchSchema<'_>> = None;
    let mut dictionaries = std::collections::HashMap::new();
    let mut batches = StreamBatches::new();
    let mut pos = 0usize;
    while let Some(frame) = next_frame(bytes, &mut pos)? {
        // Only a stream's first schema can come from the cache: a batch message never
        // matches one, and a second schema is refused below as it would be anyway.
        if schema.is_none()
            && let Some(cached) = schema_cache::lookup(&bytes[frame.metadata.clone()])
        {
            pos = body_range(bytes, &frame, cached.body_length)?.end;
            schema = Some(BatchSchema::Cached(cached));
            continue;
        }
        // A record batch message read without flatbuffers' verifier (it would accept it:
        // `batch_message`), built by our decoder; anything else takes the full path below,
        // as everything does with our decoder off (arrow-ipc's path, the fuzz oracle).
        if let Some(batch_schema) = &schema
            && batch_decoder::is_on()
            && let Some(header) = BatchHeader::read(&bytes[frame.metadata.clone()])
        {
            let body = body_range(bytes, &frame, header.body_length)?;
            let body_buffer = buffer.slice_with_length(body.start, body.len());
            if let Some((columns, rows)) =
                batch_decoder::decode_batch(&body_buffer, &header, batch_schema.fields())
            {
                pos = body.end;
                batches.push(StreamBatch {
                    schema: batch_schema.clone(),
                    columns,
                    rows,
                });
                continue;
            }
        }
        let message = verify_message(bytes, &frame)?;
        let body = body_range(bytes, &frame, message.bodyLength())?;
        pos = body.end;
        let body = buffer.slice_with_length(body.start, body.len());
        let version = message.version();
        match message.header_type() {
            MessageHeader::Schema => {
                let Some(ipc_schema) = message.header_as_schema() else {
                    return Err(unexpected("a schema message without its schema"));
                };
                if schema.is_some() {
                    return Err(unexpected("a second schema in one stream"));
                }
                let parsed = std::sync::Arc::new(arrow_ipc::convert::fb_to_schema(ipc_schema));
                schema_cache::learn(
                    &bytes[frame.metadata.clone()],
                    &parsed,
                    message.bodyLength(),
                );
                schema = Some(BatchSchema::Parsed(parsed));
            }
            MessageHeader::RecordBatch => {
                let (Some(batch), Some(batch_schema)) =
                    (message.header_as_record_batch(), schema.as_mut())
                else {
                    return Err(unexpected("a record batch before the schema"));
                };
                let context = BatchContext {
                    body: &body,
                    body_length: message.bodyLength(),
                    dictionaries: &dictionaries,
                    version: &version,
                };
                batches.push(decode_verified_batch(batch_schema, batch, &context)?);
            }
            MessageHeader::DictionaryBatch => {
                let (Some(dictionary), Some(batch_schema)) =
                    (message.header_as_dictionary_batch(), &schema)
                else {
                    return Err(unexpected("a dictionary batch before the schema"));
                };
                let full = batch_schema.full();
                arrow_ipc::reader::read_dictionary(
                    &body,
                    dictionary,
                    &full,
                    &mut dictionaries,
                    &version,
                )
                .map_err(IpcError::Ipc)?;
                schema = Some(BatchSchema::Parsed(full));
            }
            MessageHeader::NONE => {}
            other => {
                return Err(unexpected(&format!(
                    "message type {other:?} in a stream of record batches"
                )));
            }
        }
    }
    Ok(batches)
}

/// What decoding a verified record batch message needs besides its schema.
struct BatchContext<'m> {
    body: &'m Buffer,
    body_length: i64,
    dictionaries: &'m std::collections::HashMap<i64, arrow_array::ArrayRef>,
    version: &'m arrow_ipc::MetadataVersion,
}

/// A verified record batch message's batch: our decoder's where it builds it, else
/// arrow-ipc's answer (or error) with the schema in full, which `schema` then becomes (the
/// stream's later batches decode against the same fields either way).
fn decode_verified_batch<'a>(
    schema: &mut BatchSchema<'a>,
    batch: arrow_ipc::RecordBatch<'_>,
    context: &BatchContext<'_>,
) -> Result<StreamBatch<'a>, IpcError> {
    let decoded = BatchHeader::of_verified(context.body_length, batch)
        .and_then(|header| batch_decoder::decode_batch(context.body, &header, schema.fields()));
    let (columns, rows) = if let Some(decoded) = decoded {
        decoded
    } else {
        let full = schema.full();
        let decoded = arrow_ipc::reader::read_record_batch(
            context.body,
            batch,
            std::sync::Arc::clone(&full),
            context.dictionaries,
            None,
            context.version,
        )
        .map_err(IpcError::Ipc)?;
        *schema = BatchSchema::Parsed(full);
        let (_, columns, rows) = decoded.into_parts();
        (Columns::from_vec(columns), rows)
    };
    Ok(StreamBatch {
        schema: schema.clone(),
        columns,
        rows,
    })
}
