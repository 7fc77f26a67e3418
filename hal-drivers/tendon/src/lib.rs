//! The `tendon` driver process (being written).
