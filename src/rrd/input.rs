//! [`RrdInput`]: what a [`LazyRecording`](super::LazyRecording) reads from. A local file
//! answers every positioned read at the cost of a system call; an object in a bucket
//! answers each with a request over the network, so before a query reads its chunks it is
//! told all of them at once ([`RrdInput::prefetch`]) and fetches them together.

use std::io::{BufReader, Cursor, Read, Seek};
use std::ops::Range;

/// A seekable input an `.rrd` is read from lazily.
///
/// Every `Read + Seek` type in the standard library is one; an input for which a read is
/// costly (a network round trip) also implements [`RrdInput::prefetch`].
///
/// ```
/// use chunkstore::rrd::RrdInput;
/// struct Counted(std::io::Cursor<Vec<u8>>);
/// # impl std::io::Read for Counted { fn read(&mut self, b: &mut [u8]) -> std::io::Result<usize> { self.0.read(b) } }
/// # impl std::io::Seek for Counted { fn seek(&mut self, p: std::io::SeekFrom) -> std::io::Result<u64> { self.0.seek(p) } }
/// impl RrdInput for Counted {}
/// ```
pub trait RrdInput: Read + Seek {
    /// A hint: the byte ranges in `ranges` (sorted by start, not overlapping) are about to
    /// be read, each whole, in this order. An input over a network fetches them at once
    /// (coalescing neighbours) and answers the reads from what it fetched; a local file
    /// does nothing. Reads must give the same bytes whether or not this was called.
    ///
    /// # Errors
    /// If fetching fails; the reads that follow may then fail too.
    fn prefetch(&mut self, ranges: &[Range<u64>]) -> std::io::Result<()> {
        let _ = ranges;
        Ok(())
    }

    /// What reading this input has cost in requests so far: nothing for a local file; an
    /// object counts its GETs and the bytes they brought (see [`Fetched`]).
    fn fetched(&self) -> Fetched {
        Fetched::default()
    }
}

/// Requests an input made over the network and the bytes they brought, counted by the
/// input itself (so two queries at once each see their own).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub struct Fetched {
    /// GET requests (the open's included).
    pub requests: u64,
    /// Bytes the GETs brought: more than were read where neighbouring ranges were
    /// fetched in one GET with the gap between them.
    pub bytes: u64,
}

impl RrdInput for std::fs::File {}

impl<T: AsRef<[u8]>> RrdInput for Cursor<T> {}

impl<R: Read + Seek> RrdInput for BufReader<R> {}

impl<R: RrdInput + ?Sized> RrdInput for Box<R> {
    fn prefetch(&mut self, ranges: &[Range<u64>]) -> std::io::Result<()> {
        (**self).prefetch(ranges)
    }

    fn fetched(&self) -> Fetched {
        (**self).fetched()
    }
}
