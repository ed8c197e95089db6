//! Dataset folders' files for comparisons (tests/dataset.rs includes this file alone).

use std::collections::BTreeMap;
use std::path::Path;

/// Every file under the folders `subs` of `dir`, by path relative to `dir`, with its bytes.
pub fn files_under(dir: &Path, subs: &[&str]) -> BTreeMap<String, Vec<u8>> {
    let mut m = BTreeMap::new();
    for sub in subs {
        let mut stack = vec![dir.join(sub)];
        while let Some(d) = stack.pop() {
            for e in std::fs::read_dir(&d).unwrap().flatten() {
                let p = e.path();
                if p.is_dir() {
                    stack.push(p);
                } else {
                    let rel = p.strip_prefix(dir).unwrap().to_string_lossy().into_owned();
                    m.insert(rel, std::fs::read(&p).unwrap());
                }
            }
        }
    }
    m
}
