//! CPU phase timing and GPU pass timing, written as a Chrome trace (Perfetto,
//! chrome://tracing): one track per CPU thread that timed a phase, one for GPU passes.

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
    /// The CPU thread that timed it (its name, or its id); empty for GPU passes.
    #[serde(default)]
    pub thread: String,
}

/// The current thread's name, or its id when it has none.
pub fn thread_label() -> String {
    let t = std::thread::current();
    match t.name() {
        Some(n) => n.to_string(),
        None => format!("{:?}", t.id()),
    }
}

/// One value of a counter at a time (a Chrome trace counter event: Perfetto draws each
/// counter as a track of its own).
#[derive(Clone, Debug, serde::Serialize)]
pub struct CounterValue {
    pub name: String,
    pub at_us: f64,
    pub value: f64,
}

/// Collects spans (and counter values) from the whole run; shared by reference.
pub struct Profiler {
    origin: Instant,
    spans: Mutex<Vec<Span>>,
    counters: Mutex<Vec<CounterValue>>,
}

impl Default for Profiler {
    fn default() -> Self {
        Profiler {
            origin: Instant::now(),
            spans: Mutex::new(Vec::new()),
            counters: Mutex::new(Vec::new()),
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
            thread: thread_label(),
        });
        r
    }

    /// Records a CPU phase that ran from `start_us` for `dur_us` (on this thread).
    pub fn cpu_span(&self, name: &str, start_us: f64, dur_us: f64) {
        self.push(Span {
            name: name.to_string(),
            track: "cpu",
            start_us,
            dur_us,
            thread: thread_label(),
        });
    }

    /// Takes over another profiler's spans, moved onto this one's clock (a per-image
    /// profiler merged into the profile of a whole run).
    pub fn absorb(&self, other: &Profiler) {
        let shift = if other.origin >= self.origin {
            (other.origin - self.origin).as_secs_f64() * 1e6
        } else {
            -((self.origin - other.origin).as_secs_f64() * 1e6)
        };
        for mut s in other.spans() {
            s.start_us += shift;
            self.push(s);
        }
        let moved = other.counters().into_iter().map(|mut c| {
            c.at_us += shift;
            c
        });
        self.counters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .extend(moved);
    }

    /// Milliseconds covered by at least one span of `track` (overlaps counted once): for
    /// "gpu", the time the GPU was busy.
    pub fn busy_ms(&self, track: &str) -> f64 {
        let mut iv: Vec<(f64, f64)> = self
            .spans()
            .iter()
            .filter(|s| s.track == track)
            .map(|s| (s.start_us, s.start_us + s.dur_us))
            .collect();
        iv.sort_by(|a, b| a.0.total_cmp(&b.0));
        let (mut total, mut cur) = (0.0, None::<(f64, f64)>);
        for (a, b) in iv {
            cur = match cur {
                Some((s, e)) if a <= e => Some((s, e.max(b))),
                Some((s, e)) => {
                    total += e - s;
                    Some((a, b))
                }
                None => Some((a, b)),
            };
        }
        if let Some((s, e)) = cur {
            total += e - s;
        }
        total / 1e3
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

    /// Records counter `name` at `value` now.
    pub fn counter(&self, name: &str, value: f64) {
        let at_us = self.now_us();
        self.counters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .push(CounterValue {
                name: name.to_string(),
                at_us,
                value,
            });
    }

    /// Every counter value recorded, in the order recorded.
    pub fn counters(&self) -> Vec<CounterValue> {
        self.counters
            .lock()
            .unwrap_or_else(|p| p.into_inner())
            .clone()
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

    /// The Chrome trace-event JSON (complete events, "X"): GPU passes on thread 1, each
    /// CPU thread that timed a phase on its own thread (2, 3, ... in order of first use);
    /// each counter's values as counter events ("C").
    pub fn chrome_trace(&self) -> serde_json::Value {
        let spans = self.spans();
        let mut threads: Vec<String> = Vec::new();
        for s in spans.iter().filter(|s| s.track != "gpu") {
            if !threads.contains(&s.thread) {
                threads.push(s.thread.clone());
            }
        }
        let tid = |s: &Span| match s.track {
            "gpu" => 1,
            _ => 2 + threads.iter().position(|t| *t == s.thread).unwrap_or(0),
        };
        let mut events = vec![
            serde_json::json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 1, "args": {"name": "GPU passes"}}),
        ];
        for (i, t) in threads.iter().enumerate() {
            events.push(serde_json::json!({"name": "thread_name", "ph": "M", "pid": 1, "tid": 2 + i, "args": {"name": format!("CPU {t}")}}));
        }
        for s in &spans {
            events.push(serde_json::json!({
                "name": s.name, "cat": s.track, "ph": "X", "pid": 1,
                "tid": tid(s),
                "ts": s.start_us, "dur": s.dur_us,
            }));
        }
        for c in self.counters() {
            events.push(serde_json::json!({
                "name": c.name, "ph": "C", "pid": 1, "ts": c.at_us,
                "args": {"value": c.value},
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

#[cfg(test)]
mod tests {
    use super::*;

    fn span(track: &'static str, start_us: f64, dur_us: f64) -> Span {
        Span {
            name: "x".into(),
            track,
            start_us,
            dur_us,
            thread: String::new(),
        }
    }

    #[test]
    fn busy_time_counts_overlaps_once() {
        let p = Profiler::new();
        for (a, d) in [
            (0.0, 1000.0),
            (500.0, 1000.0),
            (3000.0, 500.0),
            (3100.0, 100.0),
        ] {
            p.push(span("gpu", a, d));
        }
        p.push(span("cpu", 0.0, 9000.0));
        assert!((p.busy_ms("gpu") - 2.0).abs() < 1e-9);
        assert!((p.busy_ms("cpu") - 9.0).abs() < 1e-9);
        assert_eq!(p.busy_ms("none"), 0.0);
    }

    #[test]
    fn absorbed_spans_move_onto_the_run_clock() {
        let run = Profiler::new();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let image = Profiler::new();
        image.push(span("gpu", 0.0, 10.0));
        run.absorb(&image);
        let s = &run.spans()[0];
        assert!(
            s.start_us >= 20_000.0 && s.start_us < 2_000_000.0,
            "{}",
            s.start_us
        );
        // Phases timed on two threads get two CPU tracks.
        run.cpu("main", || ());
        std::thread::scope(|sc| {
            sc.spawn(|| run.cpu("other", || ()));
        });
        let trace = run.chrome_trace();
        let names: Vec<String> = trace["traceEvents"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e["ph"] == "M")
            .map(|e| e["args"]["name"].as_str().unwrap().to_string())
            .collect();
        assert_eq!(names.len(), 3, "{names:?}");
        assert_eq!(names[0], "GPU passes");
    }

    #[test]
    fn counters_are_written_as_counter_events_on_the_run_clock() {
        let run = Profiler::new();
        std::thread::sleep(std::time::Duration::from_millis(20));
        let image = Profiler::new();
        image.counter("device memory (MiB)", 12.5);
        run.absorb(&image);
        run.counter("device memory (MiB)", 13.0);
        let c = run.counters();
        assert_eq!(c.len(), 2);
        assert!(c[0].at_us >= 20_000.0, "{}", c[0].at_us);
        let trace = run.chrome_trace();
        let values: Vec<f64> = trace["traceEvents"]
            .as_array()
            .unwrap()
            .iter()
            .filter(|e| e["ph"] == "C" && e["name"] == "device memory (MiB)")
            .map(|e| e["args"]["value"].as_f64().unwrap())
            .collect();
        assert_eq!(values, [12.5, 13.0]);
    }
}
