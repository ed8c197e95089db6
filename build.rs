//! Compiles every compute shader in glsl/ to SPIR-V with shaderc (Debian's glslang,
//! linked as .cargo/config.toml says).
//!
//! - `#include "x.glsl"` resolves relative to the including file, then to glsl/.
//! - A shader with a line `//! variants: a=DEFINE_A b=DEFINE_B` is compiled once per
//!   variant with that define, as `<name>.<variant>`; otherwise once as `<name>`.
//! - A shader error fails the build with the file:line glslang reports.
//! - Each output records a hash of its source, includes and defines; unchanged shaders
//!   are not recompiled.

use std::cell::RefCell;
use std::collections::BTreeSet;
use std::collections::hash_map::DefaultHasher;
use std::hash::{Hash, Hasher};
use std::path::{Path, PathBuf};
use std::rc::Rc;

fn main() {
    let root =
        PathBuf::from(std::env::var("CARGO_MANIFEST_DIR").expect("cargo sets CARGO_MANIFEST_DIR"));
    let glsl = root.join("glsl");
    let out = PathBuf::from(std::env::var("OUT_DIR").expect("cargo sets OUT_DIR"));
    println!("cargo:rerun-if-changed=glsl");

    let mut shaders: Vec<PathBuf> = Vec::new();
    collect(&glsl, &mut shaders);
    shaders.sort();
    let compiler = shaderc::Compiler::new().expect("shaderc compiler");
    let mut table = String::from(
        "/// (name, SPIR-V) of every compiled shader variant.\npub static SHADERS: &[(&str, &[u8])] = &[\n",
    );
    let mut failed = false;
    for path in &shaders {
        println!("cargo:rerun-if-changed={}", path.display());
        let source =
            std::fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()));
        let stem = path
            .file_stem()
            .and_then(|s| s.to_str())
            .expect("shader names are UTF-8")
            .to_string();
        for (variant, define) in variants(&source) {
            let name = match &variant {
                Some(v) => format!("{stem}.{v}"),
                None => stem.clone(),
            };
            let spv_path = out.join(format!("{name}.spv"));
            let hash_path = out.join(format!("{name}.hash"));
            let old = std::fs::read_to_string(&hash_path).unwrap_or_default();
            if let Some((h, deps)) = old.split_once('\n')
                && spv_path.exists()
                && h == input_hash(&source, deps.lines(), define.as_deref()).to_string()
            {
                table.push_str(&format!(
                    "    ({name:?}, include_bytes!({:?})),\n",
                    spv_path.display().to_string()
                ));
                for d in deps.lines() {
                    println!("cargo:rerun-if-changed={d}");
                }
                continue;
            }
            match compile(&compiler, &glsl, path, &source, define.as_deref()) {
                Ok((words, deps)) => {
                    std::fs::write(&spv_path, &words).expect("write SPIR-V");
                    let deps: Vec<String> = deps.into_iter().collect();
                    let h = input_hash(&source, deps.iter().map(|s| s.as_str()), define.as_deref());
                    std::fs::write(&hash_path, format!("{h}\n{}", deps.join("\n")))
                        .expect("write hash");
                    for d in &deps {
                        println!("cargo:rerun-if-changed={d}");
                    }
                    table.push_str(&format!(
                        "    ({name:?}, include_bytes!({:?})),\n",
                        spv_path.display().to_string()
                    ));
                }
                Err(msg) => {
                    failed = true;
                    for line in msg.lines() {
                        println!("cargo:warning={line}");
                    }
                    eprintln!("{msg}");
                }
            }
        }
    }
    if failed {
        eprintln!("shader compilation failed (see the file:line messages above)");
        std::process::exit(1);
    }
    table.push_str("];\n");
    std::fs::write(out.join("shaders.rs"), table).expect("write shaders.rs");
}

fn collect(dir: &Path, out: &mut Vec<PathBuf>) {
    let Ok(rd) = std::fs::read_dir(dir) else {
        return;
    };
    for e in rd.flatten() {
        let p = e.path();
        if p.is_dir() {
            collect(&p, out);
        } else if p.extension().and_then(|e| e.to_str()) == Some("comp") {
            out.push(p);
        }
    }
}

fn variants(source: &str) -> Vec<(Option<String>, Option<String>)> {
    for line in source.lines() {
        if let Some(rest) = line.trim().strip_prefix("//! variants:") {
            return rest
                .split_whitespace()
                .filter_map(|kv| kv.split_once('='))
                .map(|(k, v)| (Some(k.to_string()), Some(v.to_string())))
                .collect();
        }
    }
    vec![(None, None)]
}

fn input_hash<'a>(source: &str, deps: impl Iterator<Item = &'a str>, define: Option<&str>) -> u64 {
    let mut h = DefaultHasher::new();
    source.hash(&mut h);
    define.hash(&mut h);
    for d in deps {
        d.hash(&mut h);
        std::fs::read(d).unwrap_or_default().hash(&mut h);
    }
    h.finish()
}

fn compile(
    compiler: &shaderc::Compiler,
    glsl: &Path,
    path: &Path,
    source: &str,
    define: Option<&str>,
) -> Result<(Vec<u8>, BTreeSet<String>), String> {
    let deps: Rc<RefCell<BTreeSet<String>>> = Rc::default();
    let mut opts = shaderc::CompileOptions::new().map_err(|e| e.to_string())?;
    opts.set_target_env(
        shaderc::TargetEnv::Vulkan,
        shaderc::EnvVersion::Vulkan1_2 as u32,
    );
    opts.set_target_spirv(shaderc::SpirvVersion::V1_5);
    opts.set_optimization_level(shaderc::OptimizationLevel::Performance);
    opts.set_generate_debug_info();
    if let Some(d) = define {
        opts.add_macro_definition(d, Some("1"));
    }
    let glsl_dir = glsl.to_path_buf();
    let here = path.parent().map(Path::to_path_buf).unwrap_or_default();
    let deps_cb = deps.clone();
    opts.set_include_callback(move |name, _ty, includer, _depth| {
        let base = Path::new(includer)
            .parent()
            .map(Path::to_path_buf)
            .unwrap_or_else(|| here.clone());
        for candidate in [base.join(name), here.join(name), glsl_dir.join(name)] {
            if let Ok(content) = std::fs::read_to_string(&candidate) {
                let resolved = candidate.display().to_string();
                deps_cb.borrow_mut().insert(resolved.clone());
                return Ok(shaderc::ResolvedInclude {
                    resolved_name: resolved,
                    content,
                });
            }
        }
        Err(format!("cannot find include {name:?} (from {includer})"))
    });
    let artifact = compiler
        .compile_into_spirv(
            source,
            shaderc::ShaderKind::Compute,
            &path.display().to_string(),
            "main",
            Some(&opts),
        )
        .map_err(|e| match define {
            Some(d) => format!("{e}\n(in variant with {d})"),
            None => e.to_string(),
        })?;
    let bytes = artifact.as_binary_u8().to_vec();
    drop(opts);
    let deps = deps.borrow().clone();
    Ok((bytes, deps))
}
