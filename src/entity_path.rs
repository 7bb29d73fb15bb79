//! Entity paths: `/`-separated names that form a tree (`world` ⊃ `world/robot`).
//!
//! An [`EntityPath`] is an `Arc` around its parts and a hash computed once, so cloning is a
//! reference-count bump, hashing feeds one `u64`, and equality usually settles on the hash.
//! Each part carries the hash of the path up to it, so that a tree keyed by parts (the
//! Clear index, walked by every latest-at of a store holding Clears) looks a level up
//! without hashing text.

use std::cell::RefCell;
use std::cmp::Ordering;
use std::fmt::{self, Write as _};
use std::hash::{BuildHasher, Hash, Hasher};
use std::sync::Arc;

/// An entity path's text could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum EntityPathError {
    /// The empty string is not a path (the root is `/`).
    Empty,
    /// A part between two `/` is empty (`a//b`, or a trailing `/`).
    EmptyPart {
        /// The path as given.
        path: String,
        /// Which part (0-based) is empty.
        index: usize,
    },
    /// A `\` escape is malformed.
    BadEscape {
        /// The path as given.
        path: String,
        /// What is wrong with it.
        reason: &'static str,
    },
}

impl fmt::Display for EntityPathError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::Empty => write!(f, "empty entity path (the root is `/`)"),
            Self::EmptyPart { path, index } => {
                write!(
                    f,
                    "entity path {path:?} has an empty part at position {index}"
                )
            }
            Self::BadEscape { path, reason } => write!(f, "entity path {path:?}: {reason}"),
        }
    }
}

impl std::error::Error for EntityPathError {}

/// A path in the entity tree, e.g. `/world/robot/camera`. The root is `/` (no parts).
///
/// ```
/// use chunkstore::EntityPath;
/// let path: EntityPath = "/paths/with\\ space/a\\/b".parse().unwrap();
/// assert_eq!(path.parts().collect::<Vec<_>>(), ["paths", "with space", "a/b"]);
/// assert_eq!(path.to_string(), "/paths/with\\ space/a\\/b");
/// assert!(EntityPath::parse("paths").unwrap().is_ancestor_of(&path));
/// ```
#[derive(Clone)]
pub struct EntityPath {
    parts: Arc<[PathPart]>,
    /// Kept beside the pointer rather than behind it: a store hashes the path of every
    /// query, and reading the hash through the pointer would be a cache miss per query
    /// when the caller's paths are many.
    hash: u64,
}

/// Fixed seeds: a path hashes the same in every store and every run, so orders built on
/// hashes are reproducible.
const PATH_HASH_STATE: ahash::RandomState = ahash::RandomState::with_seeds(
    0x243f_6a88_85a3_08d3,
    0x1319_8a2e_0370_7344,
    0xa409_3822_299f_31d0,
    0x082e_fa98_ec4e_6c89,
);

/// One part of an [`EntityPath`] and the hash of the path up to and including it, which
/// is all a map keyed by parts hashes (see [`PrefixHasher`]). Two parts are equal if their
/// names are and the paths above them hash alike: parts of the same parent compare as
/// their names do.
#[derive(Clone, Debug)]
pub(crate) struct PathPart {
    name: Arc<str>,
    prefix_hash: u64,
}

impl PathPart {
    /// The hash of the root path, which the hash of each part extends.
    pub const ROOT_HASH: u64 = 0x9e37_79b9_7f4a_7c15;

    /// The part's unescaped text.
    pub fn name(&self) -> &Arc<str> {
        &self.name
    }

    /// The hash of the path up to and including this part.
    pub fn prefix_hash(&self) -> u64 {
        self.prefix_hash
    }

    /// Is this part's hash that of a path hashing to `parent_hash` extended by its name?
    pub fn extends(&self, parent_hash: u64) -> bool {
        self.prefix_hash == extend_hash(parent_hash, &self.name)
    }
}

impl PartialEq for PathPart {
    fn eq(&self, other: &Self) -> bool {
        self.prefix_hash == other.prefix_hash && crate::text::same_text(&self.name, &other.name)
    }
}

impl Eq for PathPart {}

impl Hash for PathPart {
    fn hash<H: Hasher>(&self, state: &mut H) {
        state.write_u64(self.prefix_hash);
    }
}

/// The hasher of maps keyed by [`PathPart`]s (or anything else hashing one well-mixed
/// `u64`): it passes that `u64` through rather than hashing it again.
#[derive(Clone, Copy, Debug, Default)]
pub(crate) struct PrefixHasher(u64);

impl Hasher for PrefixHasher {
    fn finish(&self) -> u64 {
        self.0
    }

    fn write_u64(&mut self, value: u64) {
        self.0 = value;
    }

    /// Not reached by [`PathPart`]; anything else is folded in, so a map stays correct.
    fn write(&mut self, bytes: &[u8]) {
        for &byte in bytes {
            self.0 = (self.0.rotate_left(5) ^ u64::from(byte)).wrapping_mul(0x517c_c1b7_2722_0a95);
        }
    }
}

/// A map keyed by path parts (see [`PathPart`]).
pub(crate) type PartMap<V> =
    std::collections::HashMap<PathPart, V, std::hash::BuildHasherDefault<PrefixHasher>>;

/// The hash of the path `parent` extended by `name`.
fn extend_hash(parent: u64, name: &str) -> u64 {
    let mut hasher = PATH_HASH_STATE.build_hasher();
    hasher.write_u64(parent);
    name.hash(&mut hasher);
    hasher.finish()
}

/// How many path texts [`EntityPath::parse_recent`] keeps per thread.
const RECENT_PATHS: usize = 256;
/// A longer path text is parsed every time.
const MAX_RECENT_PATH_BYTES: usize = 256;

impl EntityPath {
    /// The root path `/`.
    pub fn root() -> Self {
        Self::from_parts(Vec::<Arc<str>>::new())
    }

    /// A path from already unescaped parts. Parts may contain any character, `/` included.
    ///
    /// # Errors
    /// [`EntityPathError::EmptyPart`] if a part is empty.
    pub fn try_from_parts<S: Into<Arc<str>>>(
        parts: impl IntoIterator<Item = S>,
    ) -> Result<Self, EntityPathError> {
        let parts: Vec<Arc<str>> = parts.into_iter().map(Into::into).collect();
        if let Some(index) = parts.iter().position(|p| p.is_empty()) {
            return Err(EntityPathError::EmptyPart {
                path: join_for_error(&parts),
                index,
            });
        }
        Ok(Self::from_parts(parts))
    }

    pub(crate) fn from_parts(parts: Vec<Arc<str>>) -> Self {
        let mut hash = PathPart::ROOT_HASH;
        let parts: Arc<[PathPart]> = parts
            .into_iter()
            .map(|name| {
                hash = extend_hash(hash, &name);
                PathPart {
                    name,
                    prefix_hash: hash,
                }
            })
            .collect();
        Self { parts, hash }
    }

    /// A path from parts whose hashes are already right (a prefix of a path's, plus at most
    /// new ones pushed with [`extend_hash`]).
    fn from_hashed_parts(parts: Vec<PathPart>) -> Self {
        let hash = parts
            .last()
            .map_or(PathPart::ROOT_HASH, |part| part.prefix_hash);
        Self {
            parts: parts.into(),
            hash,
        }
    }

    /// [`EntityPath::parse`], remembered per thread for the last [`RECENT_PATHS`] texts
    /// (of at most [`MAX_RECENT_PATH_BYTES`]): a stream's chunks each name their entity in
    /// text, and parsing allocates every part. Answers never depend on it.
    pub(crate) fn parse_recent(text: &str) -> Result<Self, EntityPathError> {
        thread_local! {
            static RECENT: RefCell<ahash::HashMap<Box<str>, EntityPath>> = RefCell::default();
        }
        if let Some(path) = RECENT.with(|recent| recent.try_borrow().ok()?.get(text).cloned()) {
            return Ok(path);
        }
        let path = Self::parse(text)?;
        if text.len() <= MAX_RECENT_PATH_BYTES {
            RECENT.with(|recent| {
                if let Ok(mut recent) = recent.try_borrow_mut() {
                    // A full set starts again.
                    if recent.len() == RECENT_PATHS {
                        recent.clear();
                    }
                    recent.insert(text.into(), path.clone());
                }
            });
        }
        Ok(path)
    }

    /// Parses the text form: optional leading `/`, parts separated by `/`, `\` escaping the
    /// next character (`\n`, `\t` and `\u{XXXX}` are special; any other escaped character
    /// stands for itself).
    ///
    /// # Errors
    /// Empty parts (`a//b`, a trailing `/`), an empty string, a trailing `\`, or a bad
    /// `\u{...}` escape, each as its own [`EntityPathError`] variant.
    pub fn parse(text: &str) -> Result<Self, EntityPathError> {
        if text.is_empty() {
            return Err(EntityPathError::Empty);
        }
        let body = text.strip_prefix('/').unwrap_or(text);
        if body.is_empty() {
            return Ok(Self::root());
        }
        if body.contains('\\') {
            Self::parse_escaped(text, body)
        } else {
            Self::parse_plain(text, body)
        }
    }

    /// [`Self::parse`] of a non-empty `body` (the text without its leading `/`) holding
    /// no escape (the usual case, once per decoded chunk): each part is a slice of the
    /// text, copied once.
    fn parse_plain(text: &str, body: &str) -> Result<Self, EntityPathError> {
        let mut parts = Vec::with_capacity(body.bytes().filter(|&b| b == b'/').count() + 1);
        for (index, part) in body.split('/').enumerate() {
            if part.is_empty() {
                return Err(EntityPathError::EmptyPart {
                    path: text.to_owned(),
                    index,
                });
            }
            parts.push(Arc::<str>::from(part));
        }
        Ok(Self::from_parts(parts))
    }

    /// [`Self::parse`] of any non-empty `body`, unescaping character by character.
    fn parse_escaped(text: &str, body: &str) -> Result<Self, EntityPathError> {
        let mut parts = Vec::new();
        let mut current = String::new();
        let mut chars = body.chars();
        while let Some(c) = chars.next() {
            match c {
                '/' => {
                    if current.is_empty() {
                        return Err(EntityPathError::EmptyPart {
                            path: text.to_owned(),
                            index: parts.len(),
                        });
                    }
                    parts.push(Arc::<str>::from(std::mem::take(&mut current)));
                }
                '\\' => current.push(unescape(&mut chars, text)?),
                c => current.push(c),
            }
        }
        if current.is_empty() {
            return Err(EntityPathError::EmptyPart {
                path: text.to_owned(),
                index: parts.len(),
            });
        }
        parts.push(current.into());
        Ok(Self::from_parts(parts))
    }

    /// The unescaped parts, root first.
    pub fn parts(&self) -> impl ExactSizeIterator<Item = &str> + '_ {
        self.parts.iter().map(|p| &*p.name)
    }

    /// The shared parts with their hashes: keys of maps by part, and derived paths built
    /// without copying strings.
    pub(crate) fn path_parts(&self) -> &[PathPart] {
        &self.parts
    }

    /// Rerun's display order, which its dataframe columns follow: part by part (a parent
    /// right before its subtree), parts in natural order: parts starting with `__` last,
    /// digit runs as numbers (`cam2` < `cam10`), case ignored but as a last tie-break
    /// (upper case first). `Ord` stays plain part-by-part text order, which is cheaper and
    /// what indexes key on.
    ///
    /// ```
    /// # use chunkstore::EntityPath;
    /// let mut paths: Vec<EntityPath> = ["/cam10", "/__props", "/cam2", "/Cam20", "/cam2/a"]
    ///     .iter()
    ///     .map(|p| EntityPath::parse(p).unwrap())
    ///     .collect();
    /// paths.sort_by(EntityPath::cmp_natural);
    /// let text: Vec<String> = paths.iter().map(ToString::to_string).collect();
    /// assert_eq!(text, ["/Cam20", "/cam2", "/cam2/a", "/cam10", "/__props"]);
    /// ```
    pub fn cmp_natural(&self, other: &Self) -> Ordering {
        self.parts()
            .zip(other.parts())
            .map(|(a, b)| natural_part_order(a, b))
            .find(|order| order.is_ne())
            .unwrap_or_else(|| self.num_parts().cmp(&other.num_parts()))
    }

    /// Number of parts (0 for the root).
    pub fn num_parts(&self) -> usize {
        self.parts.len()
    }

    /// Is this the root `/`?
    pub fn is_root(&self) -> bool {
        self.parts.is_empty()
    }

    /// The parent, or `None` for the root.
    pub fn parent(&self) -> Option<Self> {
        let parts = &self.parts;
        (!parts.is_empty()).then(|| Self::from_hashed_parts(parts[..parts.len() - 1].to_vec()))
    }

    /// The strict ancestors, nearest first, ending with the root.
    pub fn ancestors(&self) -> impl Iterator<Item = Self> + '_ {
        (0..self.num_parts())
            .rev()
            .map(|n| Self::from_hashed_parts(self.parts[..n].to_vec()))
    }

    /// Is `self` a strict ancestor of `other`?
    pub fn is_ancestor_of(&self, other: &Self) -> bool {
        self.num_parts() < other.num_parts() && other.parts.starts_with(&self.parts)
    }

    /// Is `self` equal to `other` or inside its subtree?
    pub fn starts_with(&self, other: &Self) -> bool {
        self.parts.starts_with(&other.parts)
    }

    /// The path one level below this one.
    #[must_use]
    pub fn join(&self, part: impl Into<Arc<str>>) -> Self {
        let name: Arc<str> = part.into();
        let prefix_hash = extend_hash(self.hash, &name);
        let mut parts = self.parts.to_vec();
        parts.push(PathPart { name, prefix_hash });
        Self::from_hashed_parts(parts)
    }
}

fn join_for_error(parts: &[Arc<str>]) -> String {
    parts.iter().map(|p| &**p).collect::<Vec<_>>().join("/")
}

/// Reads the character(s) after a `\`.
fn unescape(chars: &mut std::str::Chars<'_>, text: &str) -> Result<char, EntityPathError> {
    let bad = |reason: &'static str| EntityPathError::BadEscape {
        path: text.to_owned(),
        reason,
    };
    match chars.next() {
        None => Err(bad("the path ends with a lone `\\`")),
        Some('n') => Ok('\n'),
        Some('t') => Ok('\t'),
        Some('u') => {
            if chars.next() != Some('{') {
                return Err(bad("`\\u` must be followed by `{hex}`"));
            }
            let mut hex = String::new();
            loop {
                match chars.next() {
                    Some('}') => break,
                    Some(c) if c.is_ascii_hexdigit() && hex.len() < 6 => hex.push(c),
                    _ => return Err(bad("`\\u{...}` needs 1 to 6 hex digits and a closing `}`")),
                }
            }
            u32::from_str_radix(&hex, 16)
                .ok()
                .and_then(char::from_u32)
                .ok_or_else(|| bad("`\\u{...}` is not a Unicode scalar value"))
        }
        Some(c) => Ok(c),
    }
}

/// Writes one part so that [`EntityPath::parse`] reads it back: ASCII letters, digits, `_`,
/// `-`, `.` and non-ASCII printable characters stay as they are; `\n` and `\t` get their
/// short escapes, other punctuation and space a `\`, other control characters `\u{..}`.
fn write_escaped(out: &mut fmt::Formatter<'_>, part: &str) -> fmt::Result {
    for c in part.chars() {
        match c {
            c if c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.') => out.write_char(c)?,
            '\n' => out.write_str("\\n")?,
            '\t' => out.write_str("\\t")?,
            c if c.is_ascii_punctuation() || c == ' ' => {
                out.write_char('\\')?;
                out.write_char(c)?;
            }
            c if c.is_control() || c.is_whitespace() => write!(out, "\\u{{{:x}}}", u32::from(c))?,
            c => out.write_char(c)?,
        }
    }
    Ok(())
}

impl fmt::Display for EntityPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        if self.is_root() {
            return f.write_char('/');
        }
        for part in self.parts() {
            f.write_char('/')?;
            write_escaped(f, part)?;
        }
        Ok(())
    }
}

impl fmt::Debug for EntityPath {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        write!(f, "{self}")
    }
}

impl std::str::FromStr for EntityPath {
    type Err = EntityPathError;
    fn from_str(s: &str) -> Result<Self, Self::Err> {
        Self::parse(s)
    }
}

impl PartialEq for EntityPath {
    fn eq(&self, other: &Self) -> bool {
        Arc::ptr_eq(&self.parts, &other.parts)
            || (self.hash == other.hash && self.parts == other.parts)
    }
}

impl Eq for EntityPath {}

impl Hash for EntityPath {
    fn hash<H: Hasher>(&self, state: &mut H) {
        state.write_u64(self.hash);
    }
}

/// Parts starting with `__` (Rerun's reserved namespace, e.g. `__properties`) come after
/// all others; otherwise digit runs compare as numbers (`cam2` < `cam10`), a run starting
/// with `0` compares digit by digit as a fraction would (`1.010` < `1.02`), and other
/// characters compare ignoring ASCII case (`a` < `B` < `b`), except that the first pair
/// differing only in case decides, upper case first (`Cam20` < `cam2`).
/// Distinct parts never compare equal. This is the order Rerun 0.41 gives its dataframe
/// columns (checked with its SDK on the parts of `tests` below).
pub(crate) fn natural_part_order(a: &str, b: &str) -> Ordering {
    let reserved = |part: &str| part.starts_with("__");
    reserved(a)
        .cmp(&reserved(b))
        .then_with(|| natural_text_order(a, b))
        .then_with(|| a.cmp(b))
}

fn natural_text_order(a: &str, b: &str) -> Ordering {
    let (mut a, mut b) = (a.chars().peekable(), b.chars().peekable());
    loop {
        let (x, y) = match (a.peek(), b.peek()) {
            (None, None) => return Ordering::Equal,
            (None, Some(_)) => return Ordering::Less,
            (Some(_), None) => return Ordering::Greater,
            (Some(&x), Some(&y)) => (x, y),
        };
        let order = match (x.to_digit(10), y.to_digit(10)) {
            (Some(0), Some(_)) | (Some(_), Some(0)) => digit_runs_as_fractions(&mut a, &mut b),
            (Some(_), Some(_)) => digit_runs_as_numbers(&mut a, &mut b),
            _ => {
                a.next();
                b.next();
                x.to_ascii_lowercase()
                    .cmp(&y.to_ascii_lowercase())
                    .then(x.cmp(&y))
            }
        };
        if order.is_ne() {
            return order;
        }
    }
}

type Chars<'a> = std::iter::Peekable<std::str::Chars<'a>>;

/// Takes the next character if it is a decimal digit.
fn next_digit(chars: &mut Chars<'_>) -> Option<u32> {
    let digit = chars.peek()?.to_digit(10)?;
    chars.next();
    Some(digit)
}

/// Two digit runs as integers: the longer run is greater; of equally long runs, the first
/// differing digit decides.
fn digit_runs_as_numbers(a: &mut Chars<'_>, b: &mut Chars<'_>) -> Ordering {
    let mut first_difference = Ordering::Equal;
    loop {
        match (next_digit(a), next_digit(b)) {
            (Some(x), Some(y)) => first_difference = first_difference.then(x.cmp(&y)),
            (Some(_), None) => return Ordering::Greater,
            (None, Some(_)) => return Ordering::Less,
            (None, None) => return first_difference,
        }
    }
}

/// Two digit runs, one starting with `0`, aligned on the left: the first differing digit
/// decides, and a run that ends first is less.
fn digit_runs_as_fractions(a: &mut Chars<'_>, b: &mut Chars<'_>) -> Ordering {
    loop {
        match (next_digit(a), next_digit(b)) {
            (Some(x), Some(y)) if x != y => return x.cmp(&y),
            (Some(_), Some(_)) => {}
            (Some(_), None) => return Ordering::Greater,
            (None, Some(_)) => return Ordering::Less,
            (None, None) => return Ordering::Equal,
        }
    }
}

impl PartialOrd for EntityPath {
    fn partial_cmp(&self, other: &Self) -> Option<Ordering> {
        Some(self.cmp(other))
    }
}

/// Orders part by part, so a parent sorts right before its subtree.
impl Ord for EntityPath {
    fn cmp(&self, other: &Self) -> Ordering {
        if Arc::ptr_eq(&self.parts, &other.parts) {
            return Ordering::Equal;
        }
        self.parts
            .iter()
            .map(|p| &p.name)
            .cmp(other.parts.iter().map(|p| &p.name))
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Text without escapes parses the same on the plain path as on the general one:
    /// parts, or the same error.
    #[test]
    fn the_plain_path_parses_as_the_escaping_one() {
        use proptest::prelude::*;
        // Its seeds beside every other property test's (`tests/core/seeds.rs`).
        let config = ProptestConfig {
            failure_persistence: Some(Box::new(
                proptest::test_runner::FileFailurePersistence::Direct(
                    "tests/proptest-regressions/lib/entity_path.txt",
                ),
            )),
            ..ProptestConfig::default()
        };
        proptest!(config, |(text in "/?[ab/é.]{1,12}")| {
            let body = text.strip_prefix('/').unwrap_or(&text);
            prop_assume!(!body.is_empty());
            let plain = EntityPath::parse_plain(&text, body);
            let escaped = EntityPath::parse_escaped(&text, body);
            match (plain, escaped) {
                (Ok(a), Ok(b)) => prop_assert_eq!(a, b),
                (Err(a), Err(b)) => prop_assert_eq!(a.to_string(), b.to_string()),
                (a, b) => prop_assert!(false, "{:?} against {:?}", a, b),
            }
        });
    }

    /// The order Rerun 0.41's dataframe gave these entities' columns (one `Scalars` logged
    /// to each, read back with `rerun.chunk.ChunkStore.reader`).
    #[test]
    fn natural_order_is_rerun_column_order() {
        let rerun_order = [
            "/1.02", "/1.1", "/10", "/A", "/a", "/a\\ 2", "/a0", "/a1a", "/a1b", "/a2", "/aa",
            "/B", "/b", "/g/q", "/g/r1", "/g/__p", "/r02", "/r2", "/r10", "/tree", "/tree/a",
            "/tree-b", "/x007", "/x2-g8", "/x2-y7", "/x7", "/Z", "/z", "/é", "/__x",
        ];
        check_order(&rerun_order);
        // A second recording: case decides at the first pair of letters differing in it.
        check_order(&[
            "/Cam3", "/Cam20", "/cAm2x", "/cam2", "/cam2/a", "/cam10", "/__props",
        ]);
    }

    /// Paths given in ascending order compare as their places do, and sort back into it.
    fn check_order(ascending: &[&str]) {
        let paths: Vec<EntityPath> = ascending
            .iter()
            .map(|p| EntityPath::parse(p).unwrap())
            .collect();
        for (i, a) in paths.iter().enumerate() {
            for (j, b) in paths.iter().enumerate() {
                assert_eq!(a.cmp_natural(b), i.cmp(&j), "{a} against {b}");
            }
        }
        let mut shuffled = paths.clone();
        shuffled.reverse();
        shuffled.sort_by(EntityPath::cmp_natural);
        assert_eq!(shuffled, paths);
    }

    #[test]
    fn natural_part_order_details() {
        use Ordering::{Equal, Greater, Less};
        assert_eq!(natural_part_order("1.001", "1.002"), Less);
        assert_eq!(natural_part_order("1.010", "1.02"), Less);
        assert_eq!(natural_part_order("x2-y8", "x8-y8"), Less);
        assert_eq!(natural_part_order("pic5.113", "pic5.13"), Greater);
        assert_eq!(
            natural_part_order("r99999999999999999999999", "r100000000000000000000000"),
            Less
        );
        assert_eq!(natural_part_order("x7", "x7"), Equal);
        assert_eq!(natural_part_order("__a", "__b"), Less);
    }

    fn parts(p: &EntityPath) -> Vec<&str> {
        p.parts().collect()
    }

    #[test]
    fn leading_slash_is_optional_and_root_is_slash() {
        assert_eq!(
            EntityPath::parse("/a/b").unwrap(),
            EntityPath::parse("a/b").unwrap()
        );
        assert!(EntityPath::parse("/").unwrap().is_root());
        assert_eq!(EntityPath::root().to_string(), "/");
    }

    #[test]
    fn empty_parts_are_errors() {
        for bad in ["a//b", "a/", "//", "/a/b/"] {
            assert!(
                matches!(
                    EntityPath::parse(bad),
                    Err(EntityPathError::EmptyPart { .. })
                ),
                "{bad:?}"
            );
        }
        assert_eq!(EntityPath::parse(""), Err(EntityPathError::Empty));
        assert!(EntityPath::try_from_parts(["a", ""]).is_err());
    }

    #[test]
    fn escapes_follow_rerun() {
        let p = EntityPath::parse(r"/paths/with\ space/a\/b").unwrap();
        assert_eq!(parts(&p), ["paths", "with space", "a/b"]);
        let p = EntityPath::parse(r"x\\y/\n\t/\u{1F600}/\:").unwrap();
        assert_eq!(parts(&p), ["x\\y", "\n\t", "😀", ":"]);
        for bad in [r"a\", r"\u{}", r"\u{110000}", r"\u1234", r"\u{12"] {
            assert!(
                matches!(
                    EntityPath::parse(bad),
                    Err(EntityPathError::BadEscape { .. })
                ),
                "{bad:?}"
            );
        }
    }

    #[test]
    fn display_round_trips_any_part() {
        let weird = [
            "a b", "a/b", "\\", "\n", "\u{7}", "ünï", "x.y-z_w", "#$%", "\u{2028}",
        ];
        let p = EntityPath::try_from_parts(weird).unwrap();
        let text = p.to_string();
        assert_eq!(EntityPath::parse(&text).unwrap(), p, "{text}");
    }

    #[test]
    fn tree_relations() {
        let abc = EntityPath::parse("a/b/c").unwrap();
        let ancestors: Vec<String> = abc.ancestors().map(|p| p.to_string()).collect();
        assert_eq!(ancestors, ["/a/b", "/a", "/"]);
        assert!(EntityPath::root().is_ancestor_of(&abc));
        assert!(!abc.is_ancestor_of(&abc));
        assert!(abc.starts_with(&abc));
        assert!(
            !EntityPath::parse("a/bc")
                .unwrap()
                .starts_with(&EntityPath::parse("a/b").unwrap())
        );
        assert_eq!(abc.parent().unwrap().join("c"), abc);
    }

    #[test]
    fn order_is_part_by_part() {
        let mut v: Vec<EntityPath> = ["a-b", "a/b", "a", "/"]
            .iter()
            .map(|s| EntityPath::parse(s).unwrap())
            .collect();
        v.sort();
        let text: Vec<String> = v.iter().map(ToString::to_string).collect();
        assert_eq!(text, ["/", "/a", "/a/b", "/a-b"]);
    }
}
