//! CPU phase timing and GPU pass timing, written as a Chrome trace (Perfetto,
//! chrome://tracing): one track for CPU phases, one for GPU passes.

use std::path::Path;
use std::sync::Mutex;
use std::time::Instant;

/// One timed slice.
#[derive(Clone, Debug, serde::Serialize)]
pub struct Span {
    pub name: String,
    /// "cpu" or "gpu".
    pub track: &'static str,
    pub start_us: f64,
    pub dur_us: f64,
}

/// Collects spans from the whole run; shared by reference.
pub struct Profiler {
    origin: Instant,
    spans: Mutex<Vec<Span>>,
}

impl Default for Profiler {
    fn default() -> Self {
        Profiler {
            origin: Instant::now(),
            spans: Mutex::new(Vec::new()),
        }
    }
}

/// Runs `f`, timed as CPU phase `name` when a profiler is given.
pub fn timed<R>(profiler: Option<&Profiler>, name: &str, f: impl FnOnce() -> R) -> R {
    match profiler {
        Some(p) => p.cpu(name, f),
        None => f(),
    }
}

impl Profiler {
    pub fn new() -> Self {
        Self::default()
    }

    /// Microseconds since the profiler was made.
    pub fn now_us(&self) -> f64 {
        self.origin.elapsed().as_secs_f64() * 1e6
    }

    /// Times a CPU phase (BVH build, upload, readback, ...).
    pub fn cpu<R>(&self, name: &str, f: impl FnOnce() -> R) -> R {
        let start = self.now_us();
        let r = f();
        let dur = self.now_us() - start;
        self.push(Span {
            name: name.to_string(),
            track: "cpu",
            start_us: start,
            dur_us: dur,
        });
        r
    }

    pub fn push(&self, span: Span) {
        self.spans
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(span);
    }

    pub fn spans(&self) -> Vec<Span> {
        self.spans.lock().unwrap_or_else(|p| p.into_inner()).clone()
    }

    /// Total duration of the spans with this name (all tracks), in milliseconds.
    pub fn total_ms(&self, name: &str) -> f64 {
        self.spans()
            .iter()
            .filter(|s| s.name == name)
            .map(|s| s.dur_us)
            .sum::<f64>()
            / 1e3
    }

    /// The Chrome trace-event JSON (complete events, "X").
    pub fn chrome_trace(&self) -> serde_json::Value {
        let mut events = vec![
            serde_json::json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 1, "args": {"name": "CPU phases"}}),
            serde_json::json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 2, "args": {"name": "GPU passes"}}),
        ];
        for s in self.spans() {
            events.push(serde_json::json!({
                "name": s.name, "cat": s.track, "ph": "X", "pid": 1,
                "tid": if s.track == "gpu" { 2 } else { 1 },
                "ts": s.start_us, "dur": s.dur_us,
            }));
        }
        serde_json::json!({"traceEvents": events, "displayTimeUnit": "ms"})
    }

    pub fn write_chrome_trace(&self, path: &Path) -> std::io::Result<()> {
        let bytes =
            serde_json::to_vec_pretty(&self.chrome_trace()).map_err(std::io::Error::other)?;
        crate::util::write_atomic(path, &bytes)
    }
}
