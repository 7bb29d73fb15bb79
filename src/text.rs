//! Equality of short names (timelines, components, path parts), which every query compares
//! a few of: `str`'s own equality calls `memcmp` whatever the length, and the call costs
//! more than comparing a name of a few bytes.

/// Are `a` and `b` the same text? Lengths first, then the same address (names are often
/// one shared copy), then the bytes: a name of up to 16 bytes as two overlapping words.
#[inline]
pub(crate) fn same_text(a: &str, b: &str) -> bool {
    let (a, b) = (a.as_bytes(), b.as_bytes());
    if a.len() != b.len() {
        return false;
    }
    if std::ptr::eq(a.as_ptr(), b.as_ptr()) {
        return true;
    }
    let n = a.len();
    match n {
        0 => true,
        1..=3 => a[0] == b[0] && a[n / 2] == b[n / 2] && a[n - 1] == b[n - 1],
        4..=8 => word::<4>(a, 0) == word::<4>(b, 0) && word::<4>(a, n - 4) == word::<4>(b, n - 4),
        9..=16 => word::<8>(a, 0) == word::<8>(b, 0) && word::<8>(a, n - 8) == word::<8>(b, n - 8),
        _ => a == b,
    }
}

/// The `N` bytes of `bytes` at `at` (in range: the callers check the length), as one load.
#[inline]
fn word<const N: usize>(bytes: &[u8], at: usize) -> [u8; N] {
    let mut out = [0; N];
    out.copy_from_slice(&bytes[at..at + N]);
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    /// Agrees with `==` on every pair of short texts differing anywhere, at every length.
    #[test]
    fn agrees_with_str_equality() {
        let base = "abcdefghijklmnopqrstuvwxyz0123456789";
        for n in 0..=base.len() {
            let a = &base[..n];
            let copy: String = a.chars().collect();
            assert!(same_text(a, &copy));
            for at in 0..n {
                let mut other = a.as_bytes().to_vec();
                other[at] = b'#';
                let other = String::from_utf8(other).expect("ASCII");
                assert!(!same_text(a, &other), "{a:?} vs {other:?}");
            }
            if n > 0 {
                assert!(!same_text(a, &base[..n - 1]));
            }
        }
        assert!(same_text("é", "é") && !same_text("é", "è"));
    }
}
