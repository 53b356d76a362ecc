//! Status codes and messages across the boundary. Every entry point runs its
//! body through [`guard`]: a failure or a panic becomes `HP_ERROR` or
//! `HP_NOT_SUPPORTED` with a message, kept per context (`hp_ctx_last_error`)
//! and per thread (`hp_last_error`, also for calls that have no context).
//! Nothing unwinds into C.

use std::cell::RefCell;
use std::ffi::{c_char, CString};
use std::panic::{catch_unwind, AssertUnwindSafe};
use std::sync::Mutex;

use crate::abi::{ERROR, NOT_SUPPORTED, OK};

/// A failed call: its status and message.
#[derive(Debug)]
pub struct Fail {
    pub status: i32,
    pub msg: String,
}

pub type Result<T> = std::result::Result<T, Fail>;

impl Fail {
    pub fn error(msg: impl Into<String>) -> Fail {
        Fail {
            status: ERROR,
            msg: msg.into(),
        }
    }

    pub fn not_supported(msg: impl Into<String>) -> Fail {
        Fail {
            status: NOT_SUPPORTED,
            msg: msg.into(),
        }
    }
}

impl From<hotpath::Error> for Fail {
    fn from(e: hotpath::Error) -> Fail {
        match e {
            hotpath::Error::NotSupported(m) => Fail::not_supported(m),
            other => Fail::error(other.to_string()),
        }
    }
}

/// The last message of a context; the pointer `hp_ctx_last_error` returns
/// stays valid until the next failing call on that context.
#[derive(Default)]
pub struct LastError(Mutex<CString>);

impl LastError {
    pub fn set(&self, msg: &str) {
        let mut g = self.0.lock().unwrap_or_else(|p| p.into_inner());
        *g = c_message(msg);
    }

    pub fn as_ptr(&self) -> *const c_char {
        self.0.lock().unwrap_or_else(|p| p.into_inner()).as_ptr()
    }
}

thread_local! {
    static THREAD_LAST: RefCell<CString> = RefCell::new(CString::default());
}

/// The calling thread's last message (valid until its next failing call).
pub fn thread_last_ptr() -> *const c_char {
    THREAD_LAST.with(|s| s.borrow().as_ptr())
}

/// A C string of `msg`: ASCII only (the header's promise), interior NULs
/// and other bytes replaced by `?`.
fn c_message(msg: &str) -> CString {
    let clean: Vec<u8> = msg
        .bytes()
        .map(|b| if b.is_ascii() && b != 0 { b } else { b'?' })
        .collect();
    CString::new(clean).unwrap_or_default()
}

/// Runs `body`; records a failure (or a caught panic) in `ctx` (when known)
/// and in the thread's slot; returns the status.
pub fn guard(ctx: Option<&LastError>, what: &str, body: impl FnOnce() -> Result<()>) -> i32 {
    let r = catch_unwind(AssertUnwindSafe(body)).unwrap_or_else(|p| {
        let why = p
            .downcast_ref::<&str>()
            .map(|s| s.to_string())
            .or_else(|| p.downcast_ref::<String>().cloned())
            .unwrap_or_else(|| "unknown panic".into());
        Err(Fail::error(format!("internal error (panic): {why}")))
    });
    match r {
        Ok(()) => OK,
        Err(f) => {
            let msg = format!("{what}: {}", f.msg);
            if let Some(c) = ctx {
                c.set(&msg);
            }
            THREAD_LAST.with(|s| *s.borrow_mut() = c_message(&msg));
            f.status
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use std::ffi::CStr;

    #[test]
    fn a_panic_becomes_an_error_with_its_message() {
        let ctx = LastError::default();
        let st = guard(Some(&ctx), "hp_test", || panic!("boom"));
        assert_eq!(st, ERROR);
        let msg = unsafe { CStr::from_ptr(ctx.as_ptr()) }.to_str().unwrap();
        assert!(
            msg.contains("hp_test: internal error (panic): boom"),
            "{msg}"
        );
    }

    #[test]
    fn messages_are_ascii_and_thread_local_too() {
        let st = guard(None, "hp_x", || Err(Fail::not_supported("naïve\0x")));
        assert_eq!(st, NOT_SUPPORTED);
        let msg = unsafe { CStr::from_ptr(thread_last_ptr()) }
            .to_str()
            .unwrap();
        assert_eq!(msg, "hp_x: na??ve?x");
    }
}
