//! The Bird tracker emulator (being written).
