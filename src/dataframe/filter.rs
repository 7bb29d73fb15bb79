//! Which entities a dataframe shows: Rerun's entity path filter expressions.

use std::fmt;

use crate::{EntityPath, EntityPathError};

/// A contents expression could not be parsed.
#[derive(Debug, Clone, PartialEq, Eq)]
#[non_exhaustive]
pub enum EntityPathFilterError {
    /// A rule has no path (`+`, `-`, or nothing but spaces).
    NoPath {
        /// The rule as given.
        rule: String,
    },
    /// `**` stands anywhere but as the last part (`/a/**/b`).
    MisplacedWildcard {
        /// The rule as given.
        rule: String,
    },
    /// The path of a rule is not an entity path.
    Path {
        /// The rule as given.
        rule: String,
        /// Why its path is not one.
        error: EntityPathError,
    },
}

impl fmt::Display for EntityPathFilterError {
    fn fmt(&self, f: &mut fmt::Formatter<'_>) -> fmt::Result {
        match self {
            Self::NoPath { rule } => write!(f, "contents rule {rule:?} names no entity path"),
            Self::MisplacedWildcard { rule } => write!(
                f,
                "contents rule {rule:?}: `**` may only end a path (`/a/**`)"
            ),
            Self::Path { rule, error } => write!(f, "contents rule {rule:?}: {error}"),
        }
    }
}

impl std::error::Error for EntityPathFilterError {}

/// One rule: include or exclude a path, or a path and its whole subtree.
#[derive(Clone, Debug, PartialEq, Eq)]
struct Rule {
    include: bool,
    path: EntityPath,
    subtree: bool,
}

impl Rule {
    fn matches(&self, entity: &EntityPath) -> bool {
        if self.subtree {
            entity.starts_with(&self.path)
        } else {
            *entity == self.path
        }
    }

    /// How specific the rule is: a longer path is more specific, and for one path the
    /// exact rule is more specific than the subtree rule.
    fn specificity(&self) -> (usize, bool) {
        (self.path.num_parts(), !self.subtree)
    }
}

/// Selects entities with Rerun's include/exclude rules, e.g.
///
/// ```text
/// + /world/**          everything under /world (and /world itself)…
/// - /world/roads/**    …but the roads…
/// /world/roads/main    …except the main road (a rule without a sign includes)
/// ```
///
/// The most specific matching rule decides (a longer path beats a shorter one; for one
/// path, the exact rule beats the subtree rule; of equal rules, the last given wins). A
/// path no rule matches is excluded, except that a filter of exclusions only starts from
/// the default selection (everything but `/__properties`), so `-/world/**` alone means
/// "all but `/world`". `/__properties` (Rerun's recording properties, not data) is
/// selected only by a rule that names it (`/__properties/**`): `/**` leaves it out, as
/// Rerun's own filters do.
///
/// ```
/// use chunkstore::{EntityPath, EntityPathFilter};
/// let filter = EntityPathFilter::parse(["/world/**", "-/world/roads/**", "+/world/roads/main"])?;
/// let is_in = |p: &str| filter.matches(&EntityPath::parse(p).unwrap());
/// assert!(is_in("/world") && is_in("/world/car") && is_in("/world/roads/main"));
/// assert!(!is_in("/world/roads/side") && !is_in("/sky"));
/// # Ok::<(), chunkstore::EntityPathFilterError>(())
/// ```
#[derive(Clone, Debug, PartialEq, Eq)]
pub struct EntityPathFilter {
    rules: Vec<Rule>,
}

impl Default for EntityPathFilter {
    /// Every entity but Rerun's `/__properties` (recording properties, not data).
    fn default() -> Self {
        Self {
            rules: vec![
                Rule {
                    include: true,
                    path: EntityPath::root(),
                    subtree: true,
                },
                properties_excluded(),
            ],
        }
    }
}

/// The first part of Rerun's recording-properties entity.
const PROPERTIES: &str = "__properties";

/// `-/__properties/**`: what every filter holds unless one of its rules names the entity.
fn properties_excluded() -> Rule {
    Rule {
        include: false,
        path: EntityPath::from_parts(vec![PROPERTIES.into()]),
        subtree: true,
    }
}

impl EntityPathFilter {
    /// Parses expressions, each one rule or several on separate lines: an optional `+`
    /// (include, the default) or `-` (exclude), then an entity path in its text form,
    /// optionally ending in `/**` for the path and its whole subtree (`/**` alone is
    /// everything). Blank lines are skipped.
    ///
    /// # Errors
    /// A rule without a path, `**` anywhere but at the end, or a path that does not parse.
    pub fn parse<S: AsRef<str>>(
        expressions: impl IntoIterator<Item = S>,
    ) -> Result<Self, EntityPathFilterError> {
        let mut rules = Vec::new();
        for expression in expressions {
            for line in expression.as_ref().lines() {
                if !line.trim().is_empty() {
                    rules.push(parse_rule(line)?);
                }
            }
        }
        if rules.iter().all(|rule| !rule.include) {
            let mut with_default = Self::default().rules;
            with_default.extend(rules);
            rules = with_default;
        } else if !rules
            .iter()
            .any(|rule| rule.path.parts().next() == Some(PROPERTIES))
        {
            // First, so that of equal rules a user's (given later) would win.
            rules.insert(0, properties_excluded());
        }
        Ok(Self { rules })
    }

    /// Is `entity` selected?
    pub fn matches(&self, entity: &EntityPath) -> bool {
        let mut best: Option<&Rule> = None;
        for rule in self.rules.iter().filter(|rule| rule.matches(entity)) {
            if best.is_none_or(|b| rule.specificity() >= b.specificity()) {
                best = Some(rule);
            }
        }
        best.is_some_and(|rule| rule.include)
    }
}

fn parse_rule(line: &str) -> Result<Rule, EntityPathFilterError> {
    let trimmed = line.trim();
    let (include, rest) = match trimmed.as_bytes().first() {
        Some(b'+') => (true, &trimmed[1..]),
        Some(b'-') => (false, &trimmed[1..]),
        _ => (true, trimmed),
    };
    let text = rest.trim_start();
    if text.is_empty() {
        return Err(EntityPathFilterError::NoPath {
            rule: trimmed.to_owned(),
        });
    }
    let (path_text, subtree) = match text.strip_suffix("**") {
        Some("" | "/") => ("/", true),
        Some(prefix) if prefix.ends_with('/') && !prefix.ends_with("\\/") => {
            (&prefix[..prefix.len() - 1], true)
        }
        _ => (text, false),
    };
    let wildcard_inside = path_text == "**"
        || path_text.starts_with("**/")
        || path_text.starts_with("/**/")
        || path_text.contains("/**/")
        || path_text.ends_with("/**");
    if wildcard_inside {
        return Err(EntityPathFilterError::MisplacedWildcard {
            rule: trimmed.to_owned(),
        });
    }
    let path = EntityPath::parse(path_text).map_err(|error| EntityPathFilterError::Path {
        rule: trimmed.to_owned(),
        error,
    })?;
    Ok(Rule {
        include,
        path,
        subtree,
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    fn path(text: &str) -> EntityPath {
        EntityPath::parse(text).unwrap()
    }

    #[test]
    fn the_default_is_everything_but_properties() {
        let filter = EntityPathFilter::default();
        assert!(filter.matches(&EntityPath::root()));
        assert!(filter.matches(&path("/world/robot")));
        assert!(!filter.matches(&path("/__properties")));
        assert!(!filter.matches(&path("/__properties/recording")));
    }

    #[test]
    fn exact_subtree_and_exclusion() {
        let filter = EntityPathFilter::parse(["/a/b", "+ /c/**", "- /c/d/**"]).unwrap();
        assert!(filter.matches(&path("a/b")));
        assert!(!filter.matches(&path("a/b/x")) && !filter.matches(&path("a")));
        assert!(filter.matches(&path("c")) && filter.matches(&path("c/x/y")));
        assert!(!filter.matches(&path("c/d")) && !filter.matches(&path("c/d/e")));
        assert!(!filter.matches(&path("z")));
    }

    #[test]
    fn the_most_specific_rule_wins_then_the_last() {
        let filter = EntityPathFilter::parse(["-/a/b/c", "/a/**", "-/a/b/**"]).unwrap();
        assert!(filter.matches(&path("a/x")));
        assert!(!filter.matches(&path("a/b/x")));
        assert!(!filter.matches(&path("a/b/c")));
        let exact_beats_subtree = EntityPathFilter::parse(["/a", "-/a/**"]).unwrap();
        assert!(exact_beats_subtree.matches(&path("a")));
        assert!(!exact_beats_subtree.matches(&path("a/b")));
        let last_wins = EntityPathFilter::parse(["-/a/**", "+/a/**"]).unwrap();
        assert!(last_wins.matches(&path("a/b")));
    }

    #[test]
    fn exclusions_alone_start_from_the_default() {
        let filter = EntityPathFilter::parse(["-/world/**"]).unwrap();
        assert!(filter.matches(&path("/sky")));
        assert!(!filter.matches(&path("/world/x")));
        assert!(!filter.matches(&path("/__properties")));
    }

    #[test]
    fn several_rules_on_lines_and_the_root_subtree() {
        let filter = EntityPathFilter::parse(["+ /**\n\n- /x/**\n"]).unwrap();
        // Issue 32, item 11: as Rerun, `/**` leaves the properties out unless named.
        assert!(!filter.matches(&path("/__properties")));
        assert!(filter.matches(&path("/world")));
        let named = EntityPathFilter::parse(["/**", "/__properties/**"]).unwrap();
        assert!(named.matches(&path("/__properties")) && named.matches(&path("/world")));
        let exact = EntityPathFilter::parse(["/__properties"]).unwrap();
        assert!(exact.matches(&path("/__properties")));
        assert!(!filter.matches(&path("/x")));
        assert!(EntityPathFilter::parse(["**"]).unwrap().matches(&path("q")));
    }

    #[test]
    fn escaped_stars_and_spaces_are_literal() {
        let filter = EntityPathFilter::parse([r"/a/\*\*", r"/with\ space/**"]).unwrap();
        assert!(filter.matches(&EntityPath::from_parts(vec!["a".into(), "**".into()])));
        assert!(!filter.matches(&path("a/b")));
        assert!(filter.matches(&path(r"/with\ space/x")));
    }

    #[test]
    fn bad_rules_are_named() {
        for (rule, expected) in [
            ("+", "names no entity path"),
            ("-   ", "names no entity path"),
            ("/a/**/b", "`**` may only end a path"),
            ("**/a", "`**` may only end a path"),
            ("/a/**/**", "`**` may only end a path"),
            ("/a//b", "empty part"),
            ("/a/\\", "lone"),
        ] {
            let error = EntityPathFilter::parse([rule]).unwrap_err().to_string();
            assert!(error.contains(expected), "{rule:?}: {error}");
        }
    }
}
