//! Row and chunk identifiers: 128-bit ids, totally ordered as unsigned integers, and the
//! process-wide generator that hands out strictly increasing ones.

use std::fmt;
use std::time::{SystemTime, UNIX_EPOCH};

use arrow_schema::DataType;
use parking_lot::Mutex;

/// The Arrow type of a row id or chunk id column: 16 big-endian bytes, as Rerun writes them.
pub(crate) const ID_DATA_TYPE: DataType = DataType::FixedSizeBinary(ID_BYTES);

/// The bytes of a row id or chunk id.
pub(crate) const ID_BYTES: i32 = 16;

/// The state of the process-wide id generator, shared by [`RowId`] and [`ChunkId`].
///
/// One generator for both keeps every id of the process unique, so a row id can never
/// collide with a chunk id in a log a person reads.
static GENERATOR: Mutex<Option<Generator>> = Mutex::new(None);

/// The last id handed out, as its two halves.
struct Generator {
    /// Nanoseconds since the Unix epoch (or later, after clock ties and steps back).
    time_ns: u64,
    /// Incremented for every id; starts at a random value per process.
    inc: u64,
}

/// A strictly increasing 128-bit id, laid out as a TUID: the high 64 bits are nanoseconds
/// since the Unix epoch, the low 64 bits a counter that starts at a random value in each
/// process and grows by one per id. Two processes minting ids in the same nanosecond (two
/// SDK clients, two converters) then still differ in the low half, where a counter that
/// started at zero in both would collide, and a collision would lose data (the store
/// refuses a second chunk under one id).
fn next_id() -> u128 {
    let now_ns = SystemTime::now()
        .duration_since(UNIX_EPOCH)
        .map_or(0, |d| u64::try_from(d.as_nanos()).unwrap_or(u64::MAX));
    let mut state = GENERATOR.lock();
    let state = state.get_or_insert_with(|| Generator {
        time_ns: 0,
        inc: random_u64(),
    });
    state.inc = state.inc.wrapping_add(1);
    if now_ns > state.time_ns {
        state.time_ns = now_ns;
    } else if state.inc == 0 {
        // The counter wrapped within one nanosecond (or while the clock stood still or
        // stepped back): the high half moves on, so the id still grows.
        state.time_ns = state.time_ns.wrapping_add(1);
    }
    (u128::from(state.time_ns) << 64) | u128::from(state.inc)
}

/// 64 random bits from the standard library's per-process hash keys (drawn from the
/// operating system's randomness), mixed with the process id and the clock: no crate for
/// randomness is needed for one draw per process.
fn random_u64() -> u64 {
    use std::hash::{BuildHasher as _, Hasher as _};
    let mut hasher = std::collections::hash_map::RandomState::new().build_hasher();
    hasher.write_u32(std::process::id());
    hasher.write_u128(
        SystemTime::now()
            .duration_since(UNIX_EPOCH)
            .map_or(0, |d| d.as_nanos()),
    );
    hasher.finish()
}

macro_rules! define_id {
    ($(#[$doc:meta])* $name:ident) => {
        $(#[$doc])*
        #[derive(Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash, Default)]
        pub struct $name(u128);

        impl $name {
            /// The smallest id.
            pub const ZERO: Self = Self(0);
            /// The greatest id.
            pub const MAX: Self = Self(u128::MAX);

            /// A new id, strictly greater than every id this process generated before.
            pub fn new() -> Self {
                Self(next_id())
            }

            /// Wraps a raw 128-bit value.
            pub const fn from_u128(value: u128) -> Self {
                Self(value)
            }

            /// The raw 128-bit value.
            pub const fn as_u128(self) -> u128 {
                self.0
            }

            /// The 16 big-endian bytes used in Arrow (`FixedSizeBinary(16)`).
            pub const fn to_be_bytes(self) -> [u8; 16] {
                self.0.to_be_bytes()
            }

            /// Reads 16 big-endian bytes.
            pub const fn from_be_bytes(bytes: [u8; 16]) -> Self {
                Self(u128::from_be_bytes(bytes))
            }

            /// The id right after this one (saturating), e.g. for the next row of a batch.
            #[must_use]
            pub const fn next(self) -> Self {
                Self(self.0.saturating_add(1))
            }
        }

        impl fmt::Debug for $name {
            fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
                fmt::Display::fmt(self, f)
            }
        }
    };
}

define_id!(
    /// Identifies one row. Rows with equal time are ordered by row id.
    RowId
);
define_id!(
    /// Identifies one chunk; text form `chunk_` followed by 32 hex digits.
    ChunkId
);

impl fmt::Display for RowId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{:032x}", self.0)
    }
}

impl fmt::Display for ChunkId {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "chunk_{:032x}", self.0)
    }
}

/// The text was not `chunk_` followed by exactly 32 hex digits.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct ParseChunkIdError {
    /// The text that failed to parse.
    pub text: String,
}

impl fmt::Display for ParseChunkIdError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(
            f,
            "invalid chunk id {:?}: expected `chunk_` and 32 hex digits",
            self.text
        )
    }
}

impl std::error::Error for ParseChunkIdError {}

/// Each byte's value as a hex digit, either case; `0xFF` for a byte that is none.
const HEX_DIGITS: [u8; 256] = {
    let mut table = [0xFF_u8; 256];
    let mut digit = 0_u8;
    while digit < 10 {
        table[(b'0' + digit) as usize] = digit;
        digit += 1;
    }
    let mut letter = 0_u8;
    while letter < 6 {
        table[(b'a' + letter) as usize] = 10 + letter;
        table[(b'A' + letter) as usize] = 10 + letter;
        letter += 1;
    }
    table
};

impl std::str::FromStr for ChunkId {
    type Err = ParseChunkIdError;

    /// Parses `chunk_` + 32 hex digits, case-insensitively (Rerun writes mixed case).
    fn from_str(text: &str) -> Result<Self, Self::Err> {
        let err = || ParseChunkIdError {
            text: text.to_owned(),
        };
        let hex = text
            .get(..6)
            .filter(|prefix| prefix.eq_ignore_ascii_case("chunk_"))
            .and_then(|_| text.get(6..))
            .ok_or_else(err)?;
        if hex.len() != 32 {
            return Err(err());
        }
        // Through a table, in two 64-bit halves: every chunk of a file names its id this
        // way. A `match` per digit shifting one u128 took 2.5 times as long, and the
        // general radix parser several times that.
        let half = |digits: &[u8]| {
            let mut value = 0_u64;
            // Any bit past a nibble's four marks a byte that is no digit.
            let mut bad = 0_u8;
            for &digit in digits {
                let nibble = HEX_DIGITS[usize::from(digit)];
                bad |= nibble;
                value = (value << 4) | u64::from(nibble & 0xF);
            }
            (bad & !0xF == 0).then_some(value)
        };
        let (high, low) = hex.as_bytes().split_at(16);
        let (Some(high), Some(low)) = (half(high), half(low)) else {
            return Err(err());
        };
        Ok(Self((u128::from(high) << 64) | u128::from(low)))
    }
}

impl RowId {
    /// Row ids as an Arrow column the way Rerun writes them: `FixedSizeBinary(16)`, 16
    /// big-endian bytes each ([`RowId::to_be_bytes`]), no nulls.
    ///
    /// ```
    /// use arrow_array::Array;
    /// use chunkstore::RowId;
    /// let column = RowId::array([RowId::from_u128(1), RowId::from_u128(2)]);
    /// assert_eq!(column.len(), 2);
    /// assert_eq!(column.data_type(), &arrow_schema::DataType::FixedSizeBinary(16));
    /// ```
    pub fn array(row_ids: impl IntoIterator<Item = RowId>) -> arrow_array::ArrayRef {
        let bytes: Vec<u8> = row_ids.into_iter().flat_map(RowId::to_be_bytes).collect();
        std::sync::Arc::new(arrow_array::FixedSizeBinaryArray::new(
            16,
            arrow_buffer::Buffer::from_vec(bytes),
            None,
        ))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn generated_ids_strictly_increase() {
        let mut previous = RowId::new();
        for _ in 0..10_000 {
            let id = RowId::new();
            assert!(id > previous, "generator must be strictly increasing");
            previous = id;
        }
        assert!(
            ChunkId::new().as_u128() > previous.as_u128(),
            "one generator serves both kinds"
        );
    }

    /// Issue 32, item 5: the low half is a per-process random start plus a counter, not
    /// zero (ids minted in two processes in one nanosecond must still differ).
    #[test]
    fn the_low_half_is_not_zero_and_counts_up() {
        let ids: Vec<u128> = (0..1_000).map(|_| RowId::new().as_u128()).collect();
        let low = |id: u128| u64::try_from(id & u128::from(u64::MAX)).unwrap();
        assert!(ids.iter().all(|&id| low(id) != 0), "{:x}", ids[0]);
        for pair in ids.windows(2) {
            // One step per id the process mints (other tests' threads mint some too).
            let step = low(pair[1]).wrapping_sub(low(pair[0]));
            assert!((1..1 << 40).contains(&step), "{step}");
        }
        // Two draws of the per-process start differ (2^-64 odds of a false failure).
        assert_ne!(random_u64(), random_u64());
    }

    #[test]
    fn chunk_id_text_round_trips_case_insensitively() {
        let id: ChunkId = "chunk_18EA10AFD776AA1F6deffa92d8abe82a".parse().unwrap();
        assert_eq!(id.as_u128(), 0x18EA_10AF_D776_AA1F_6DEF_FA92_D8AB_E82A);
        assert_eq!(id.to_string(), "chunk_18ea10afd776aa1f6deffa92d8abe82a");
        assert_eq!(id.to_string().parse::<ChunkId>().unwrap(), id);
        assert!(
            "CHUNK_18EA10AFD776AA1F6deffa92d8abe82a"
                .parse::<ChunkId>()
                .is_ok()
        );
        for bad in [
            "",
            "chunk_",
            "chunk_123",
            "row_18EA10AFD776AA1F6deffa92d8abe82a",
            "chunk_18EA10AFD776AA1F6deffa92d8abe82g",
            "chunk_g8EA10AFD776AA1F6deffa92d8abe82a",
            "chunk_18EA10AFD776AA1F-deffa92d8abe82a",
            // 32 bytes but 31 characters: a two-byte character where two digits belong.
            "chunk_\u{e9}EA10AFD776AA1F6deffa92d8abe82a",
        ] {
            assert!(bad.parse::<ChunkId>().is_err(), "{bad:?} must not parse");
        }
    }

    #[test]
    fn be_bytes_round_trip_and_order() {
        let a = RowId::from_u128(1 << 70);
        let b = RowId::from_u128((1 << 70) + 1);
        assert_eq!(RowId::from_be_bytes(a.to_be_bytes()), a);
        assert!(
            a.to_be_bytes() < b.to_be_bytes(),
            "big-endian bytes sort like the integers"
        );
    }
}
