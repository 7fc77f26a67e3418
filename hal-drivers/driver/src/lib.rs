//! What every driver process shares (being written).
