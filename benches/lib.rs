//! Criterion benches for the workspace; run with `cargo bench -p openlcb-benches`.
