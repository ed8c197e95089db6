//! Expansion of a job into its ordered list of images, with per-item seeds and the
//! train/val/test split.
//!
//! Order: object, then its finishes, then defective instances 0.., then defect-free
//! instances 0.., then views. Finish-major keeps one finish's textures the working set
//! of the texture cache; instance-major lets the renderer keep one mesh for its views.

use rand::{Rng, SeedableRng};
use serde::{Deserialize, Serialize};

use super::job::{Job, RoughnessConvention, parse_view};
use super::seed::{derive, name, tag};

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Label {
    Defective,
    DefectFree,
}

impl Label {
    fn key(self) -> u64 {
        match self {
            Label::Defective => 1,
            Label::DefectFree => 2,
        }
    }
    pub fn short(self) -> &'static str {
        match self {
            Label::Defective => "d",
            Label::DefectFree => "f",
        }
    }
}

#[derive(Clone, Copy, Debug, PartialEq, Eq, Hash, PartialOrd, Ord, Serialize, Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Split {
    Train,
    Val,
    Test,
}

impl Split {
    pub const ALL: [Split; 3] = [Split::Train, Split::Val, Split::Test];
    pub fn name(self) -> &'static str {
        match self {
            Split::Train => "train",
            Split::Val => "val",
            Split::Test => "test",
        }
    }
}

/// One object instance: an object in one finish, defective (with a defect set) or not.
#[derive(Clone, Debug, PartialEq)]
pub struct InstancePlan {
    /// "object/finish/d007" (d = defective, f = defect-free).
    pub id: String,
    pub object: usize,
    pub finish: usize,
    pub label: Label,
    pub number: u32,
    pub defect_set: Option<usize>,
    pub split: Split,
    pub seed: u64,
}

/// One image.
#[derive(Clone, Debug, PartialEq)]
pub struct ItemPlan {
    pub index: usize,
    /// Index into [`Plan::instances`].
    pub instance: usize,
    /// Index into the job's viewpoints (`Job::viewpoints`: views, plan views, poses).
    pub view: usize,
    pub seed: u64,
}

impl ItemPlan {
    /// Folder name and manifest id: the index, zero-padded.
    pub fn id(&self) -> String {
        format!("{:06}", self.index)
    }
}

#[derive(Clone, Debug, PartialEq)]
pub struct Plan {
    pub instances: Vec<InstancePlan>,
    pub items: Vec<ItemPlan>,
}

/// The texture choice on one face of an instance.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct FaceChoice {
    pub face: u8,
    pub texture: u32,
    pub rotation_deg: f64,
    pub offset_px: [f64; 2],
}

/// Per-instance random choices, all from the instance seed.
#[derive(Clone, Debug, PartialEq, Serialize, Deserialize)]
pub struct InstanceParams {
    /// GGX alpha of the object's material.
    pub alpha: f64,
    /// The same as appleseed / Disney roughness r = sqrt(alpha).
    pub roughness: f64,
    pub faces: Vec<FaceChoice>,
}

/// Splits `n` instances by `ratios` (largest remainder, ties to the earlier split), in
/// an order shuffled by `seed`. Result: the split of instance number 0..n.
pub fn assign_splits(n: usize, ratios: [f64; 3], seed: u64) -> Vec<Split> {
    let exact: Vec<f64> = ratios.iter().map(|r| r * n as f64).collect();
    let mut counts: Vec<usize> = exact.iter().map(|e| e.floor() as usize).collect();
    let mut left = n - counts.iter().sum::<usize>().min(n);
    let mut order: Vec<usize> = (0..3).collect();
    order.sort_by(|&a, &b| {
        (exact[b] - exact[b].floor())
            .total_cmp(&(exact[a] - exact[a].floor()))
            .then(a.cmp(&b))
    });
    for &k in order.iter().cycle() {
        if left == 0 {
            break;
        }
        counts[k] += 1;
        left -= 1;
    }
    let mut perm: Vec<usize> = (0..n).collect();
    let mut rng = rand_pcg::Pcg64::seed_from_u64(seed);
    for i in (1..n).rev() {
        let j = rng.random_range(0..=i);
        perm.swap(i, j);
    }
    let mut out = vec![Split::Train; n];
    let mut k = 0;
    for (s, &c) in Split::ALL.iter().zip(&counts) {
        for _ in 0..c {
            out[perm[k]] = *s;
            k += 1;
        }
    }
    out
}

/// Expands a validated job.
///
/// Splits are by instance number within each label: defective instance j (which
/// carries defect set j) is in the same split for every object and finish, so no
/// defect geometry is seen in two splits; ratios hold within each label, so each split
/// is label-balanced like the whole.
pub fn expand(job: &Job) -> Plan {
    let ratios = [job.split.train, job.split.val, job.split.test];
    let max_of = |f: fn(&super::job::Object) -> i64| {
        job.objects
            .iter()
            .map(|o| f(o).max(0) as usize)
            .max()
            .unwrap_or(0)
    };
    let defective_splits = assign_splits(
        max_of(|o| o.defective),
        ratios,
        derive(job.seed, &[tag::SPLIT, Label::Defective.key()]),
    );
    let free_splits = assign_splits(
        max_of(|o| o.defect_free),
        ratios,
        derive(job.seed, &[tag::SPLIT, Label::DefectFree.key()]),
    );
    let sets = job.defect_sets().max(1);
    let viewpoints: Vec<String> = job
        .viewpoints()
        .iter()
        .map(|v| v.name().to_string())
        .collect();
    let mut instances = Vec::new();
    let mut items = Vec::new();
    for (oi, o) in job.objects.iter().enumerate() {
        for fi in job.object_finishes(oi) {
            let fname = &job.finishes[fi].name;
            for (label, count) in [
                (Label::Defective, o.defective),
                (Label::DefectFree, o.defect_free),
            ] {
                for number in 0..count.max(0) as u32 {
                    let key = [name(&o.name), name(fname), label.key(), number as u64];
                    let seed = derive(job.seed, &[tag::OBJECT, key[0], key[1], key[2], key[3]]);
                    let split = match label {
                        Label::Defective => defective_splits[number as usize],
                        Label::DefectFree => free_splits[number as usize],
                    };
                    let inst = instances.len();
                    instances.push(InstancePlan {
                        id: format!("{}/{}/{}{:03}", o.name, fname, label.short(), number),
                        object: oi,
                        finish: fi,
                        label,
                        number,
                        defect_set: (label == Label::Defective).then_some(number as usize % sets),
                        split,
                        seed,
                    });
                    for (vi, v) in viewpoints.iter().enumerate() {
                        items.push(ItemPlan {
                            index: items.len(),
                            instance: inst,
                            view: vi,
                            seed: derive(
                                job.seed,
                                &[tag::IMAGE, key[0], key[1], key[2], key[3], name(v)],
                            ),
                        });
                    }
                }
            }
        }
    }
    Plan { instances, items }
}

/// The random choices of one instance: material roughness (GGX alpha and r), and per inspected face its texture
/// instance, rotation and translation.
pub fn instance_params(job: &Job, inst: &InstancePlan) -> InstanceParams {
    let mut rng = rand_pcg::Pcg64::seed_from_u64(inst.seed);
    let ([lo, hi], conv) = job.material.range();
    let drawn = if hi > lo {
        rng.random_range(lo..=hi)
    } else {
        lo
    };
    let alpha = match conv {
        RoughnessConvention::Roughness => drawn * drawn,
        RoughnessConvention::Alpha => drawn,
    };
    let n = job.finishes[inst.finish].textures.max(1) as u32;
    let rot = job.mapping.rotation_deg;
    let faces = (1u8..=3)
        .map(|face| {
            let t = job.mapping.translation_px.for_face(face);
            let texture = rng.random_range(0..n);
            let rotation_deg = if rot > 0.0 {
                rng.random_range(-rot..=rot)
            } else {
                0.0
            };
            let mut off = || {
                if t > 0.0 {
                    rng.random_range(-t..=t)
                } else {
                    0.0
                }
            };
            let offset_px = [off(), off()];
            FaceChoice {
                face,
                texture,
                rotation_deg,
                offset_px,
            }
        })
        .collect();
    InstanceParams {
        alpha,
        roughness: alpha.sqrt(),
        faces,
    }
}

/// The face a view looks at.
pub fn view_face(view: &str) -> u8 {
    parse_view(view).map(|v| v.0).unwrap_or(0)
}
