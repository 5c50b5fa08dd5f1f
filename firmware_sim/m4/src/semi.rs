//! Output and exit through ARM semihosting (QEMU `-semihosting-config enable=on,target=native`
//! puts it on its own stdout and turns the exit call into its exit status).

use core::fmt;

use cortex_m_semihosting::{debug, hio};

/// Longest line sent in one semihosting call; a longer line is sent in pieces.
const LINE: usize = 512;

/// A `fmt::Write` that sends whole lines, one semihosting call per line instead of one per
/// formatted fragment (each call is a trap into QEMU).
pub struct Out {
    buf: [u8; LINE],
    len: usize,
}

impl Out {
    pub const fn new() -> Self {
        Self { buf: [0; LINE], len: 0 }
    }

    /// Sends what is buffered.
    pub fn flush(&mut self) -> fmt::Result {
        let pending = self.buf.get(..self.len).ok_or(fmt::Error)?;
        self.len = 0;
        if pending.is_empty() {
            return Ok(());
        }
        hio::hstdout()
            .and_then(|mut s| s.write_all(pending))
            .map_err(|()| fmt::Error)
    }
}

impl fmt::Write for Out {
    fn write_str(&mut self, s: &str) -> fmt::Result {
        for &b in s.as_bytes() {
            if self.len == LINE {
                self.flush()?;
            }
            if let Some(slot) = self.buf.get_mut(self.len) {
                *slot = b;
                self.len += 1;
            }
            if b == b'\n' {
                self.flush()?;
            }
        }
        Ok(())
    }
}

/// Ends the QEMU run: exit status 0 when `ok`, 1 otherwise.
pub fn exit(ok: bool) -> ! {
    debug::exit(if ok { debug::EXIT_SUCCESS } else { debug::EXIT_FAILURE });
    // Only reached without a semihosting host (a real board): stay here.
    loop {
        cortex_m::asm::wfi();
    }
}

/// Reports a fatal condition on the host's stderr and exits with failure.
pub fn fail(args: fmt::Arguments<'_>) -> ! {
    if let Ok(mut e) = hio::hstderr() {
        let _ = fmt::Write::write_fmt(&mut e, args);
        let _ = fmt::Write::write_str(&mut e, "\n");
    }
    exit(false)
}
