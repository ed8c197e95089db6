//! The module graph points one way: a module imports only modules of lower layers
//! (docs/architecture.md). Checked on the source text: every `crate::<module>` path in
//! a module's files must name a module of the same or a lower layer.

use std::path::Path;

/// Lowest first. Leaves (no imports of other modules) share layer 0.
const LAYERS: &[(&str, u32)] = &[
    ("util", 0),
    ("image_io", 0),
    ("shaders", 0),
    ("gpu_interface", 0),
    ("vk", 1),
    ("graph", 2),
    ("trace", 3),
    ("texture", 4),
    ("scene", 5),
    ("defect", 6),
    ("render", 7),
    ("metrics", 8),
    ("dataset", 9),
    ("cli", 10),
];

fn layer(name: &str) -> Option<u32> {
    LAYERS.iter().find(|(n, _)| *n == name).map(|(_, l)| *l)
}

fn files(dir: &Path, out: &mut Vec<std::path::PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let p = e.path();
        if p.is_dir() {
            files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn no_module_imports_a_higher_one() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut violations = Vec::new();
    let mut checked = 0;
    for &(module, own) in LAYERS {
        let mut paths = Vec::new();
        let dir = src.join(module);
        if dir.is_dir() {
            files(&dir, &mut paths);
        } else {
            paths.push(src.join(format!("{module}.rs")));
        }
        for p in paths {
            let text = std::fs::read_to_string(&p).unwrap();
            for (i, line) in text.lines().enumerate() {
                for (pos, _) in line.match_indices("crate::") {
                    let rest = &line[pos + "crate::".len()..];
                    let name: String = rest
                        .chars()
                        .take_while(|c| c.is_ascii_alphanumeric() || *c == '_')
                        .collect();
                    checked += 1;
                    match layer(&name) {
                        Some(l) if l > own => violations.push(format!(
                            "{}:{}: {module} (layer {own}) imports {name} (layer {l})",
                            p.display(),
                            i + 1
                        )),
                        Some(_) => {}
                        None => violations.push(format!(
                            "{}:{}: unknown module {name:?}: add it to LAYERS",
                            p.display(),
                            i + 1
                        )),
                    }
                }
            }
        }
    }
    assert!(checked > 100, "only {checked} crate paths found");
    assert!(violations.is_empty(), "{}", violations.join("\n"));
}
