//! The body of the `ipc_insert` fuzz target: arbitrary bytes as an Arrow IPC file or
//! stream of chunk batches. Decoding either fails with an error or gives chunks, which then
//! go through everything a store does ([`super::lifecycle::exercise`]).

pub fn ipc_insert(bytes: &[u8]) {
    let Ok(chunks) = chunkstore::ipc::read_chunks_from_bytes(bytes) else {
        return;
    };
    super::lifecycle::exercise(chunks);
}
