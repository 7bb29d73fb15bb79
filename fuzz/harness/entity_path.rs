//! The body of the `entity_path` fuzz target: arbitrary text parsed as an entity path.
//! Parsing either fails with an error that displays, or gives a path whose text form
//! parses back to the same path, whose parts are all non-empty and rebuild it, and whose
//! tree relations (parent, ancestors) agree. The same text as dataframe contents rules
//! (one per line): parsed or refused with an error that displays; a parsed filter selects
//! a path its own rules name exactly when the most specific of them includes it.

use chunkstore::{EntityPath, EntityPathFilter};

pub fn entity_path(bytes: &[u8]) {
    let Ok(text) = std::str::from_utf8(bytes) else {
        return;
    };
    match EntityPathFilter::parse([text]) {
        Ok(filter) => {
            if let Ok(path) = EntityPath::parse(text.trim()) {
                // A single exact rule selects its own path.
                if !text.contains('\n')
                    && !text.trim().starts_with(['+', '-'])
                    && !text.trim().ends_with("**")
                {
                    assert!(filter.matches(&path), "{text:?} selects itself");
                }
            }
        }
        Err(error) => assert!(!error.to_string().is_empty(), "an error says what is wrong"),
    }
    let path = match EntityPath::parse(text) {
        Ok(path) => path,
        Err(error) => {
            assert!(!error.to_string().is_empty(), "an error says what is wrong");
            return;
        }
    };
    let printed = path.to_string();
    let again = EntityPath::parse(&printed).expect("a path's text form parses");
    assert_eq!(again, path, "text form round trip of {text:?}");
    assert_eq!(again.to_string(), printed, "the text form is canonical");
    assert!(path.parts().all(|part| !part.is_empty()), "no empty part");
    let rebuilt = EntityPath::try_from_parts(path.parts()).expect("its own parts are valid");
    assert_eq!(rebuilt, path);
    assert_eq!(path.is_root(), path.num_parts() == 0);
    let ancestors: Vec<EntityPath> = path.ancestors().collect();
    assert_eq!(ancestors.len(), path.num_parts(), "one ancestor per level");
    assert_eq!(ancestors.first().cloned(), path.parent());
    for ancestor in &ancestors {
        assert!(ancestor.is_ancestor_of(&path) && path.starts_with(ancestor));
        assert!(!path.is_ancestor_of(ancestor));
    }
    assert!(!path.is_ancestor_of(&path) && path.starts_with(&path));
}
