//! The Dynamixel bus emulator (being written).
