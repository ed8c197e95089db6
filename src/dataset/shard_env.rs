//! Which shard a process renders: `--shard i/n`, else a Slurm array task, else a
//! Kubernetes indexed job (`JOB_COMPLETION_INDEX` with a shard count), else the whole
//! job. Ambiguous or incomplete settings are refused, never guessed.

use super::runner::Shard;

/// Where the shard came from.
#[derive(Clone, Copy, Debug, PartialEq, Eq)]
pub enum ShardSource {
    Flag,
    Slurm,
    Kubernetes,
    Whole,
}

/// Resolves the shard from `--shard`, `--shard-count` and the environment (`env` looks a
/// variable up; the CLI passes `std::env::var`). Errors say what to pass instead.
pub fn resolve_shard(
    shard: Option<&str>,
    shard_count: Option<usize>,
    env: &dyn Fn(&str) -> Option<String>,
) -> Result<(Shard, ShardSource), String> {
    let num = |name: &str| -> Result<Option<usize>, String> {
        match env(name) {
            None => Ok(None),
            Some(v) => v
                .trim()
                .parse()
                .map(Some)
                .map_err(|_| format!("{name}={v:?} is not a non-negative integer")),
        }
    };
    let slurm_id = num("SLURM_ARRAY_TASK_ID")?;
    let k8s_index = num("JOB_COMPLETION_INDEX")?;
    let env_count = num("SYNOSIS_SHARD_COUNT")?;
    if let Some(s) = shard {
        if shard_count.is_some() {
            return Err(
                "--shard and --shard-count together: give --shard i/n alone (--shard-count pairs with JOB_COMPLETION_INDEX)"
                    .into(),
            );
        }
        let sh = Shard::parse(s)
            .ok_or_else(|| format!("--shard {s:?}: expected i/n with 0 <= i < n"))?;
        return Ok((sh, ShardSource::Flag));
    }
    if slurm_id.is_some() && k8s_index.is_some() {
        return Err(
            "both SLURM_ARRAY_TASK_ID and JOB_COMPLETION_INDEX are set: which one numbers the shards is ambiguous; pass --shard i/n"
                .into(),
        );
    }
    if let Some(id) = slurm_id {
        if shard_count.is_some() || env_count.is_some() {
            return Err(
                "--shard-count / SYNOSIS_SHARD_COUNT pair with JOB_COMPLETION_INDEX, but this is a Slurm array task (the count comes from SLURM_ARRAY_TASK_COUNT): drop them, or pass --shard i/n"
                    .into(),
            );
        }
        let count = num("SLURM_ARRAY_TASK_COUNT")?
            .ok_or("SLURM_ARRAY_TASK_ID is set without SLURM_ARRAY_TASK_COUNT: pass --shard i/n")?;
        let min = num("SLURM_ARRAY_TASK_MIN")?.unwrap_or(0);
        let step = num("SLURM_ARRAY_TASK_STEP")?.unwrap_or(1);
        if step == 0 {
            return Err("SLURM_ARRAY_TASK_STEP=0".into());
        }
        let off = id.checked_sub(min).ok_or_else(|| {
            format!("SLURM_ARRAY_TASK_ID={id} is below SLURM_ARRAY_TASK_MIN={min}")
        })?;
        let index = off / step;
        if off % step != 0 || count == 0 || index >= count {
            return Err(format!(
                "Slurm array task {id} is not one of {count} evenly spaced tasks from {min} with step {step} \
                 (an array given as a list?): submit `--array=0-{}` (a step, `%` throttle and a 1-based start are fine), \
                 or pass --shard i/n",
                count.saturating_sub(1)
            ));
        }
        return Ok((Shard { index, count }, ShardSource::Slurm));
    }
    if let Some(index) = k8s_index {
        let count = shard_count.or(env_count).ok_or(
            "JOB_COMPLETION_INDEX is set: give the shard count with --shard-count or SYNOSIS_SHARD_COUNT",
        )?;
        if let (Some(a), Some(b)) = (shard_count, env_count)
            && a != b
        {
            return Err(format!(
                "--shard-count {a} and SYNOSIS_SHARD_COUNT={b} differ: give one"
            ));
        }
        if count == 0 || index >= count {
            return Err(format!("JOB_COMPLETION_INDEX={index} is not in 0..{count}"));
        }
        return Ok((Shard { index, count }, ShardSource::Kubernetes));
    }
    if shard_count.is_some() || env_count.is_some() {
        return Err(
            "--shard-count (or SYNOSIS_SHARD_COUNT) without JOB_COMPLETION_INDEX: this process would render the whole job; \
             set JOB_COMPLETION_INDEX (Kubernetes indexed job) or pass --shard i/n"
                .into(),
        );
    }
    Ok((Shard::ALL, ShardSource::Whole))
}

/// The one shard layout whose work a folder holds, when it holds exactly one shard's
/// manifest (`shard-i-of-n.jsonl`, n > 1) and nothing else: a resubmitted single array
/// task (`sbatch --array=2`, a one-task array) resumes that shard, not the whole job.
pub fn single_shard_in(dir: &std::path::Path) -> Option<Shard> {
    let rd = std::fs::read_dir(dir.join("manifests")).ok()?;
    let mut found = Vec::new();
    for e in rd.flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if let Some(s) = name
            .strip_prefix("shard-")
            .and_then(|n| n.strip_suffix(".jsonl"))
        {
            let (i, n) = s.split_once("-of-")?;
            found.push(Shard {
                index: i.parse().ok()?,
                count: n.parse().ok()?,
            });
        }
    }
    match found.as_slice() {
        [s] if s.count > 1 => Some(*s),
        _ => None,
    }
}
