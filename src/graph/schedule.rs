//! Scheduling (pure): the passes' declared buffer accesses -> dependencies -> culling ->
//! execution order.
//!
//! A pass depends on the last earlier pass that wrote a buffer it touches
//! (read-after-write, write-after-write) and, if it writes, on every earlier pass that
//! read the buffer since that write (write-after-read). Read-after-read orders nothing.
//! A pass is kept when it writes an imported buffer or a kept pass depends on it; the
//! rest feed no result and are culled. The order is a topological order of the kept
//! passes, the earliest-declared ready pass first (so, as every dependency points to an
//! earlier declaration, the kept passes in declaration order).

use std::collections::HashMap;

use super::Access;

/// Execution order of the passes (indices into `accesses`, one slice of
/// `(buffer, access)` per pass); `imported[r]` tells whether buffer `r` is the caller's.
pub(super) fn schedule(accesses: &[&[(usize, Access)]], imported: &[bool]) -> Vec<usize> {
    let deps = dependencies(accesses);
    let keep = live(accesses, &deps, imported);
    topological(&deps, &keep)
}

/// For each pass, the earlier passes it must run after (with repeats, as declared).
pub(super) fn dependencies(accesses: &[&[(usize, Access)]]) -> Vec<Vec<usize>> {
    let n = accesses.len();
    let mut deps: Vec<Vec<usize>> = vec![Vec::new(); n];
    let mut last_writer: HashMap<usize, usize> = HashMap::new();
    let mut readers: HashMap<usize, Vec<usize>> = HashMap::new();
    for (i, pass) in accesses.iter().enumerate() {
        for &(r, a) in pass.iter() {
            if let Some(&w) = last_writer.get(&r) {
                deps[i].push(w);
            }
            if a.writes() {
                deps[i].extend(
                    readers
                        .remove(&r)
                        .unwrap_or_default()
                        .into_iter()
                        .filter(|&x| x != i),
                );
            }
        }
        for &(r, a) in pass.iter() {
            if a.writes() {
                last_writer.insert(r, i);
            } else {
                readers.entry(r).or_default().push(i);
            }
        }
    }
    deps
}

/// Culling: passes that write an imported buffer, and everything they depend on.
pub(super) fn live(
    accesses: &[&[(usize, Access)]],
    deps: &[Vec<usize>],
    imported: &[bool],
) -> Vec<bool> {
    let n = accesses.len();
    let mut keep = vec![false; n];
    let mut stack: Vec<usize> = (0..n)
        .filter(|&i| accesses[i].iter().any(|&(r, a)| a.writes() && imported[r]))
        .collect();
    while let Some(i) = stack.pop() {
        if !keep[i] {
            keep[i] = true;
            stack.extend(deps[i].iter().copied());
        }
    }
    keep
}

/// Kahn's algorithm over the kept passes, always taking the earliest-declared ready pass.
pub(super) fn topological(deps: &[Vec<usize>], keep: &[bool]) -> Vec<usize> {
    let n = deps.len();
    let mut indeg: Vec<usize> = (0..n)
        .map(|i| deps[i].iter().filter(|&&d| keep[d]).count())
        .collect();
    let mut order = Vec::new();
    let mut done = vec![false; n];
    while let Some(i) = (0..n).find(|&i| keep[i] && !done[i] && indeg[i] == 0) {
        done[i] = true;
        order.push(i);
        for j in 0..n {
            if keep[j] && !done[j] {
                indeg[j] -= deps[j].iter().filter(|&&d| d == i).count();
            }
        }
    }
    order
}

#[cfg(test)]
mod tests {
    use super::super::Access::{Read, ReadWrite, Write};
    use super::*;

    fn deps_of(passes: &[&[(usize, Access)]]) -> Vec<Vec<usize>> {
        dependencies(passes)
            .into_iter()
            .map(|mut d| {
                d.sort_unstable();
                d
            })
            .collect()
    }

    #[test]
    fn read_after_write_depends_on_the_writer() {
        let d = deps_of(&[&[(0, Write)], &[(0, Read), (1, Write)]]);
        assert_eq!(d, vec![vec![], vec![0]]);
    }

    #[test]
    fn write_after_read_depends_on_every_reader_since_the_last_write() {
        // 0 writes b0, 1 and 2 read it, 3 overwrites it: 3 after 0 (WAW), 1 and 2 (WAR).
        let d = deps_of(&[
            &[(0, Write)],
            &[(0, Read), (1, Write)],
            &[(0, Read), (2, Write)],
            &[(0, Write)],
            &[(0, Read), (3, Write)],
        ]);
        assert_eq!(d[3], vec![0, 1, 2]);
        // The readers were consumed by the write: the next reader depends on 3 only.
        assert_eq!(d[4], vec![3]);
    }

    #[test]
    fn write_after_write_depends_on_the_last_writer_only() {
        let d = deps_of(&[&[(0, Write)], &[(0, Write)], &[(0, ReadWrite)]]);
        assert_eq!(d, vec![vec![], vec![0], vec![1]]);
    }

    #[test]
    fn read_after_read_orders_nothing() {
        let d = deps_of(&[&[(0, Read), (1, Write)], &[(0, Read), (2, Write)]]);
        assert_eq!(d, vec![Vec::<usize>::new(), vec![]]);
    }

    #[test]
    fn a_pass_reading_and_writing_one_buffer_does_not_depend_on_itself() {
        let d = deps_of(&[&[(0, Read), (0, Write)], &[(0, Read), (0, Write)]]);
        assert!(d[0].is_empty());
        // Pass 1 depends on pass 0 (RAW, WAW and WAR: repeats are harmless).
        assert!(!d[1].is_empty() && d[1].iter().all(|&x| x == 0), "{d:?}");
    }

    #[test]
    fn independent_passes_keep_declaration_order() {
        // Buffers 0..3 imported; nothing depends on anything.
        let passes: Vec<&[(usize, Access)]> = vec![
            &[(2, Write)],
            &[(0, Write)],
            &[(1, Write)],
            &[(3, ReadWrite)],
        ];
        assert_eq!(schedule(&passes, &[true; 4]), vec![0, 1, 2, 3]);
    }

    #[test]
    fn passes_that_feed_no_imported_buffer_are_culled() {
        // Buffers 0, 1 transient, 2 imported.
        let passes: Vec<&[(usize, Access)]> = vec![
            &[(0, Write)],            // 0: feeds 2 through 0 -> 2
            &[(1, Write)],            // 1: feeds only 1, which only 3 reads
            &[(0, Read), (2, Write)], // 2: result
            &[(1, Read), (0, Write)], // 3: overwrites 0 after 2 read it; nobody reads
            &[(2, Read)],             // 4: reads the result, writes nothing
        ];
        let imported = [false, false, true];
        assert_eq!(schedule(&passes, &imported), vec![0, 2]);
    }

    #[test]
    fn a_pass_reading_an_imported_buffer_is_not_a_result() {
        let passes: Vec<&[(usize, Access)]> = vec![&[(0, Read), (1, Write)]];
        assert_eq!(schedule(&passes, &[true, false]), Vec::<usize>::new());
    }

    #[test]
    fn the_graph_test_scenario_orders_as_declared() {
        // tests/graph.rs: a, b, unused transient; o, o2 imported (3, 4).
        let passes: Vec<&[(usize, Access)]> = vec![
            &[(0, Write)],            // fill a
            &[(2, Write)],            // dead pass
            &[(0, Read), (1, Write)], // a to b
            &[(0, Write)],            // overwrite a (after "a to b": WAR)
            &[(1, Read), (3, Write)], // b to out
            &[(0, Read), (4, Write)], // a to out2
        ];
        let imported = [false, false, false, true, true];
        let deps = deps_of(&passes);
        assert_eq!(deps[3], vec![0, 2]);
        assert_eq!(schedule(&passes, &imported), vec![0, 2, 3, 4, 5]);
    }

    #[test]
    fn topological_order_respects_dependencies_and_ties_by_declaration() {
        // Dependencies given directly (the executor only ever makes backward ones, but
        // the sort does not rely on it): 0 after 2, 1 free, 2 free.
        let deps = vec![vec![2], vec![], vec![]];
        assert_eq!(topological(&deps, &[true; 3]), vec![1, 2, 0]);
        // A culled dependency does not hold a pass back.
        assert_eq!(topological(&deps, &[true, true, false]), vec![0, 1]);
    }
}
