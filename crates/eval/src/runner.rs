//! The experiment matrix runner: cells x methods x seeds, cached and resumable.
