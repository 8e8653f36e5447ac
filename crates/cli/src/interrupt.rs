//! Ctrl-C: the first press cancels the running render through its token
//! ([`nimbus_render::Cancel`]), which stops within about a second and leaves no partial output;
//! a second press exits at once.

use std::sync::OnceLock;
use std::sync::atomic::{AtomicU32, Ordering};

use nimbus_render::Cancel;

/// The exit status of a process stopped by SIGINT, as shells report it (128 + 2).
pub const EXIT: i32 = 130;

static TOKEN: OnceLock<Cancel> = OnceLock::new();
static PRESSES: AtomicU32 = AtomicU32::new(0);

/// The token Ctrl-C sets (the handler is installed on first use). Without a handler (one could
/// not be installed) the token is still live and Ctrl-C ends the process as usual.
pub fn token() -> Cancel {
    TOKEN
        .get_or_init(|| {
            let token = Cancel::new();
            let set = token.clone();
            let _ = ctrlc::set_handler(move || {
                if PRESSES.fetch_add(1, Ordering::SeqCst) == 0 {
                    eprintln!("\ncancelling (Ctrl-C again to exit at once)");
                    set.cancel();
                } else {
                    std::process::exit(EXIT);
                }
            });
            token
        })
        .clone()
}
