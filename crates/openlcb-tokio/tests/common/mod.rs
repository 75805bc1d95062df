//! What the socket tests share: every wait has a deadline.

use std::future::Future;
use std::time::Duration;

/// No single step of a test may take longer than this.
pub(crate) const LIMIT: Duration = Duration::from_secs(120);

/// Runs `future` to its end, or panics naming `what` after [`LIMIT`].
pub(crate) async fn bounded<T>(what: &str, future: impl Future<Output = T>) -> T {
    match tokio::time::timeout(LIMIT, future).await {
        Ok(value) => value,
        Err(_) => panic!("{what} did not finish within {LIMIT:?}"),
    }
}
