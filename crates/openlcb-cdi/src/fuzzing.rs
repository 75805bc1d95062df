//! Fuzzing entry points (`cargo fuzz`, see `fuzz/`). Not part of the public API.

use alloc::vec::Vec;

use crate::{Cdi, EntryKind, Layout, Value, backup};

/// Any text: parsing never panics; the layout and its keys are a pure function of the tree
/// (laying out the same tree twice, or a re-parse of the same text, gives the same result);
/// every entry lies inside its space; and each entry's value, decoded from any bytes and
/// encoded again, comes back unchanged when encoding accepts it.
pub fn cdi_layout(data: &[u8]) {
    let Ok(text) = core::str::from_utf8(data) else { return };
    let Ok(cdi) = Cdi::parse(text) else { return };
    assert_eq!(Cdi::parse(text).as_ref(), Ok(&cdi), "parsing is deterministic");
    let Ok(layout) = Layout::new(&cdi) else { return };
    assert_eq!(Layout::new(&cdi.clone()), Ok(layout.clone()), "the layout is a function of the tree");
    let keys: Vec<&str> = layout.entries().map(|e| e.key.as_str()).collect();
    for (entry, key) in layout.entries().zip(&keys) {
        assert_eq!(entry.key, *key);
        assert!(u64::from(entry.address) + u64::from(entry.size) <= 1 << 32);
        let prefix = layout.segments.iter().any(|s| entry.key.starts_with(&s.key));
        assert!(prefix, "every key starts with its segment's");
        let seed: Vec<u8> = data.iter().copied().cycle().take(entry.size.min(64) as usize).collect();
        if seed.len() == entry.size as usize {
            roundtrip(entry, &seed);
        }
    }
    let mut snapshot = backup::Snapshot::new();
    for span in layout.spans() {
        snapshot.insert(span, data.iter().copied().cycle().take(span.len.min(4096) as usize).collect());
    }
    if let Ok(text) = backup::write(&layout, &snapshot) {
        let lines = backup::parse(&text).expect("our backup parses");
        let plan = backup::plan(&layout, &snapshot, &lines).expect("planned");
        assert!(plan.unknown_keys.is_empty(), "our own keys are all known");
        assert!(
            plan.writes.iter().all(|c| matches!(c.entry.kind, EntryKind::String)),
            "only strings re-encode differently (cut at NUL)"
        );
    }
}

fn roundtrip(entry: &crate::Entry, bytes: &[u8]) {
    let Ok(value) = entry.decode(bytes) else { return };
    let Ok(encoded) = entry.encode(&value) else { return };
    let again = entry.decode(&encoded).expect("encoded bytes decode");
    match (&value, &again) {
        (Value::Float(a), Value::Float(b)) if a.is_nan() => assert!(b.is_nan()),
        _ => assert_eq!(again, value, "decode(encode(v)) == v"),
    }
    let text = alloc::format!("{value}");
    assert_eq!(entry.parse(&text), Ok(value), "a value's text parses back");
}
