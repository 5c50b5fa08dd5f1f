//! Progress bars that suit where stderr goes: drawn in place on a terminal, and written as a
//! plain line at most once a minute where it is a file (a `nohup` log, a Slurm job's output),
//! where indicatif would draw nothing.

use std::io::IsTerminal as _;

use indicatif::{ProgressBar, ProgressDrawTarget, ProgressStyle, TermLike};

/// How often a bar writes a line into a log.
const LOG_INTERVAL: std::time::Duration = std::time::Duration::from_secs(60);

/// A bar over `len` items drawn with `template` (indicatif's template syntax).
pub fn bar(len: u64, template: &str) -> ProgressBar {
    let style = ProgressStyle::with_template(template).unwrap_or_else(|_| ProgressStyle::default_bar());
    if std::io::stderr().is_terminal() {
        ProgressBar::new(len).with_style(style)
    } else {
        ProgressBar::with_draw_target(Some(len), log_target()).with_style(style)
    }
}

/// A bar of unknown length showing `message`: a spinner on a terminal, the message and the
/// elapsed time in a log.
pub fn spinner(message: String) -> ProgressBar {
    let bar = if std::io::stderr().is_terminal() {
        ProgressBar::new_spinner()
    } else {
        let style = ProgressStyle::with_template("{msg} [{elapsed_precise}]")
            .unwrap_or_else(|_| ProgressStyle::default_spinner());
        ProgressBar::with_draw_target(None, log_target()).with_style(style)
    };
    bar.set_message(message);
    bar.enable_steady_tick(std::time::Duration::from_millis(200));
    bar
}

fn log_target() -> ProgressDrawTarget {
    ProgressDrawTarget::term_like_with_hz(Box::new(LogLines::new(LogSink::Stderr, LOG_INTERVAL)), 1)
}

/// Where a [`LogLines`] writes.
#[derive(Debug)]
enum LogSink {
    Stderr,
    #[cfg(test)]
    Memory(std::sync::Arc<std::sync::Mutex<Vec<String>>>),
}

/// A bar's drawing as plain lines, the first at once and then at most one every `every`: what
/// a log file can hold of a bar that a terminal would redraw in place.
#[derive(Debug)]
struct LogLines {
    sink: LogSink,
    every: std::time::Duration,
    /// When a line was last written, and the line drawn since.
    state: std::sync::Mutex<(Option<std::time::Instant>, String)>,
}

impl LogLines {
    fn new(sink: LogSink, every: std::time::Duration) -> Self {
        Self {
            sink,
            every,
            state: std::sync::Mutex::new((None, String::new())),
        }
    }

    fn draw(&self, s: &str) {
        if !s.trim().is_empty() {
            if let Ok(mut state) = self.state.lock() {
                state.1 = s.trim_end().to_string();
            }
        }
    }
}

impl TermLike for LogLines {
    fn width(&self) -> u16 {
        120
    }
    fn move_cursor_up(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_down(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_right(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn move_cursor_left(&self, _: usize) -> std::io::Result<()> {
        Ok(())
    }
    fn write_line(&self, s: &str) -> std::io::Result<()> {
        self.draw(s);
        Ok(())
    }
    fn write_str(&self, s: &str) -> std::io::Result<()> {
        self.draw(s);
        Ok(())
    }
    fn clear_line(&self) -> std::io::Result<()> {
        Ok(())
    }
    fn flush(&self) -> std::io::Result<()> {
        self.write_pending(false)
    }
}

impl Drop for LogLines {
    /// The bar's last drawing (its final count and time), which the interval may have held back.
    fn drop(&mut self) {
        let _ = self.write_pending(true);
    }
}

impl LogLines {
    /// Writes the line drawn since the last one, when the interval has passed or `now`.
    fn write_pending(&self, now: bool) -> std::io::Result<()> {
        let Ok(mut state) = self.state.lock() else {
            return Ok(());
        };
        let due = now || state.0.is_none_or(|last| last.elapsed() >= self.every);
        if !due || state.1.is_empty() {
            return Ok(());
        }
        let line = std::mem::take(&mut state.1);
        state.0 = Some(std::time::Instant::now());
        match &self.sink {
            LogSink::Stderr => {
                use std::io::Write as _;
                writeln!(std::io::stderr(), "{line}")
            }
            #[cfg(test)]
            LogSink::Memory(lines) => {
                if let Ok(mut lines) = lines.lock() {
                    lines.push(line);
                }
                Ok(())
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// In a log (no terminal) a bar is written as plain lines: each drawing when the interval is
    /// zero; within an interval only the first, and the last when the bar goes.
    #[test]
    fn a_bar_in_a_log_is_written_as_lines_at_most_once_an_interval() {
        use std::sync::{Arc, Mutex};
        use std::time::Duration;
        let drawn = |every: Duration| {
            let lines = Arc::new(Mutex::new(Vec::new()));
            let log = LogLines::new(LogSink::Memory(lines.clone()), every);
            let bar = ProgressBar::with_draw_target(Some(10), ProgressDrawTarget::term_like(Box::new(log)))
                .with_style(ProgressStyle::with_template("{pos}/{len} records").unwrap());
            for _ in 0..3 {
                bar.inc(1);
            }
            bar.finish();
            let before_drop = lines.lock().unwrap().clone();
            drop(bar);
            let written = lines.lock().unwrap().clone();
            (before_drop, written)
        };
        let (_, every) = drawn(Duration::ZERO);
        assert!(every.iter().any(|l| l == "3/10 records"), "{every:?}");
        assert!(every.iter().all(|l| l.ends_with("/10 records")), "{every:?}");
        assert!(every.len() > 2, "{every:?}");
        let (held, hourly) = drawn(Duration::from_secs(3600));
        assert_eq!(held.len(), 1, "{held:?}");
        assert_eq!(hourly.len(), 2, "{hourly:?}");
        // The finished bar, held back by the interval, is written when it goes.
        assert_eq!(hourly[1], "10/10 records", "{hourly:?}");
    }
}
