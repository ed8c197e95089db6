//! The production [`TextureSource`]: the texture module (`crate::texture`). A finish's
//! `params` / `variation` / `exemplar` tables are the texture module's own structs
//! (`MilledParams`, `MilledVariation`, `SandblastParams`, `StandInExemplar`), so their
//! fields, defaults and ranges are documented once, in docs/texture.md.

use std::collections::HashMap;
use std::sync::Arc;

use rand::SeedableRng;

use super::job::{Finish, FinishKind};
use super::renderer::TextureMap;
use super::seed::{derive, name};
use super::textures::{TextureSource, TextureWant};
use crate::texture::{
    HeightMap, MilledParams, MilledVariation, NoProgress, SandblastParams, StandInExemplar,
    generate_milled, generate_sandblasted,
};

fn table<T: serde::de::DeserializeOwned>(t: &toml::Table, what: &str) -> Result<T, String> {
    toml::Value::Table(t.clone())
        .try_into()
        .map_err(|e| format!("{what}: {e}"))
}

/// How a milled finish varies between texture instances.
enum Variation {
    None,
    Sets(MilledVariation),
}

fn milled(f: &Finish) -> Result<(MilledParams, Variation), String> {
    let p: MilledParams = table(&f.params, "params")?;
    p.validate().map_err(|e| format!("params: {e}"))?;
    let v = match &f.variation {
        None => Variation::None,
        Some(toml::Value::String(s)) if s == "none" => Variation::None,
        Some(toml::Value::String(s)) if s == "paper" => Variation::Sets(MilledVariation::default()),
        Some(toml::Value::Table(t)) => Variation::Sets(table(t, "variation")?),
        Some(_) => return Err("variation: \"paper\", \"none\" or a table of value sets".into()),
    };
    Ok((p, v))
}

fn sandblasted(f: &Finish) -> Result<(SandblastParams, StandInExemplar), String> {
    let p: SandblastParams = table(&f.params, "params")?;
    p.validate().map_err(|e| format!("params: {e}"))?;
    let ex: StandInExemplar = match &f.exemplar {
        Some(t) => table(t, "exemplar")?,
        None => StandInExemplar::default(),
    };
    ex.validate().map_err(|e| format!("exemplar: {e}"))?;
    Ok((p, ex))
}

/// Checks a finish's texture parameters with the texture module's own validation.
pub fn validate(f: &Finish) -> Result<(), String> {
    match f.kind {
        FinishKind::Milled => milled(f).map(|_| ()),
        FinishKind::Sandblasted => sandblasted(f).map(|_| ()),
    }
}

/// Textures from `crate::texture`; keeps one exemplar per sandblasted finish (its
/// measurement, or the stand-in) and one loaded measurement per finish.
#[derive(Default)]
pub struct ModuleTextures {
    exemplars: HashMap<String, Arc<HeightMap>>,
    measurements: HashMap<String, Arc<HeightMap>>,
}

impl ModuleTextures {
    /// The finish's measurement, form-removed (loaded once per finish).
    fn measurement(&mut self, f: &Finish) -> Result<Option<Arc<HeightMap>>, String> {
        let Some(m) = &f.measurement else {
            return Ok(None);
        };
        if let Some(h) = self.measurements.get(&f.name) {
            return Ok(Some(h.clone()));
        }
        let h = crate::texture::load_measurement(&m.resolved, m.unit, m.exr_spacing_um, m.form)
            .map_err(|e| format!("measurement: {e}"))?;
        let h = Arc::new(h);
        self.measurements.insert(f.name.clone(), h.clone());
        Ok(Some(h))
    }

    /// Loads or makes what `finish`'s textures share (its measurement, its sandblasted
    /// exemplar), once per finish, so that [`ModuleTextures::make_ready`] only reads.
    fn ready(&mut self, f: &Finish) -> Result<(), String> {
        self.measurement(f)?;
        if f.kind == FinishKind::Sandblasted && !self.exemplars.contains_key(&f.name) {
            let (_, ex) = sandblasted(f)?;
            let e = match self.measurement(f)? {
                Some(m) => m,
                // One exemplar per finish, seeded by its name (not the job seed): it
                // stands in for a measurement of the real surface.
                None => Arc::new(ex.generate(name(&f.name)).map_err(|e| e.to_string())?),
            };
            self.exemplars.insert(f.name.clone(), e);
        }
        Ok(())
    }

    /// One texture of a finish made [`ModuleTextures::ready`].
    fn make_ready(
        &self,
        f: &Finish,
        seed: u64,
        size: usize,
        spacing_um: f64,
    ) -> Result<TextureMap, String> {
        let height = match f.kind {
            FinishKind::Milled => {
                let (mut base, var) = milled(f)?;
                if let Some(m) = self.measurements.get(&f.name) {
                    base.moments = m.moments();
                }
                let p = match var {
                    Variation::None => base,
                    Variation::Sets(v) => {
                        let mut rng = rand_pcg::Pcg64::seed_from_u64(derive(seed, &[1]));
                        v.sample(&base, &mut rng)
                    }
                };
                generate_milled(&p, size, size, spacing_um, seed, &NoProgress)
                    .map_err(|e| e.to_string())?
            }
            FinishKind::Sandblasted => {
                let (p, _) = sandblasted(f)?;
                let exemplar = self
                    .exemplars
                    .get(&f.name)
                    .ok_or_else(|| format!("finish {}: no exemplar made", f.name))?;
                generate_sandblasted(exemplar, &p, size, size, spacing_um, seed, &NoProgress)
                    .map_err(|e| e.to_string())?
            }
        };
        Ok(height.slopes())
    }
}

impl TextureSource for ModuleTextures {
    fn make(
        &mut self,
        f: &Finish,
        _instance: u32,
        seed: u64,
        size: usize,
        spacing_um: f64,
    ) -> Result<TextureMap, String> {
        self.ready(f)?;
        self.make_ready(f, seed, size, spacing_um)
    }

    /// Side by side on rayon's pool (each texture's synthesis is parallel too; one
    /// image's two or three faces together keep more of the cores busy).
    fn make_many(&mut self, wants: &[TextureWant<'_>]) -> Vec<Result<TextureMap, String>> {
        use rayon::prelude::*;
        let ready: Vec<Result<(), String>> = wants.iter().map(|w| self.ready(w.finish)).collect();
        let this = &*self;
        wants
            .par_iter()
            .zip(ready)
            .map(|(w, r)| {
                r.and_then(|()| this.make_ready(w.finish, w.seed, w.size_px, w.spacing_um))
            })
            .collect()
    }
}
