//! Pseudo-terminals that stand in for serial ports: a driver opens the slave's path as it would
//! open `/dev/ttyUSB0`, the emulator reads and writes the master.

use std::fs::File;
use std::io::{self, Read, Write};
use std::os::fd::{AsFd, OwnedFd};
use std::os::unix::fs::OpenOptionsExt;
use std::path::{Path, PathBuf};
use std::time::Duration;

use nix::fcntl::OFlag;
use nix::poll::{PollFd, PollFlags, PollTimeout, poll};
use nix::pty::{grantpt, posix_openpt, ptsname_r, unlockpt};
use nix::sys::termios::{SetArg, cfmakeraw, tcgetattr, tcsetattr};

/// One pseudo-terminal pair. The slave stays open here too, so the master never reads a hang-up
/// (EIO) while no driver has the device open, and a driver may close and reopen it.
#[derive(Debug)]
pub struct Pty {
    master: File,
    slave: OwnedFd,
    slave_path: PathBuf,
}

impl Pty {
    /// Opens a pair in raw mode (no echo, no line editing, 8 data bits), as a serial port is.
    /// Both ends are close-on-exec from the start: a process the caller starts (a driver under
    /// test) must not hold the device open, or closing it here would never hang up the line.
    pub fn open() -> io::Result<Self> {
        let cloexec = OFlag::O_RDWR | OFlag::O_NOCTTY | OFlag::O_CLOEXEC;
        let master = posix_openpt(cloexec).map_err(io::Error::from)?;
        grantpt(&master).map_err(io::Error::from)?;
        unlockpt(&master).map_err(io::Error::from)?;
        let slave_path = PathBuf::from(ptsname_r(&master).map_err(io::Error::from)?);
        let slave = OwnedFd::from(
            std::fs::OpenOptions::new()
                .read(true)
                .write(true)
                .custom_flags(cloexec.bits())
                .open(&slave_path)?,
        );
        let mut t = tcgetattr(&slave).map_err(io::Error::from)?;
        cfmakeraw(&mut t);
        tcsetattr(&slave, SetArg::TCSANOW, &t).map_err(io::Error::from)?;
        Ok(Self {
            master: File::from(OwnedFd::from(master)),
            slave,
            slave_path,
        })
    }

    /// The device path a driver opens (`/dev/pts/N`).
    pub fn path(&self) -> &Path {
        &self.slave_path
    }

    /// Reads what the driver wrote: waits at most `timeout`, returns 0 when nothing came.
    pub fn read_timeout(&mut self, buf: &mut [u8], timeout: Duration) -> io::Result<usize> {
        let ms = timeout.as_millis().min(u16::MAX as u128) as u16;
        let mut fds = [PollFd::new(self.master.as_fd(), PollFlags::POLLIN)];
        match poll(&mut fds, PollTimeout::from(ms)) {
            Ok(0) => Ok(0),
            Ok(_) => self.master.read(buf),
            Err(nix::errno::Errno::EINTR) => Ok(0),
            Err(e) => Err(e.into()),
        }
    }

    /// The device end as a file of its own (a duplicate of the slave kept open here), for a
    /// reader in this process.
    pub fn slave_file(&self) -> io::Result<File> {
        Ok(File::from(self.slave.try_clone()?))
    }

    /// Sends bytes to the driver.
    pub fn write_all(&mut self, bytes: &[u8]) -> io::Result<()> {
        self.master.write_all(bytes)
    }

    /// Drops whatever the driver side has not read yet (a device that was unplugged and plugged
    /// in again starts with an empty line).
    pub fn discard_pending(&self) -> io::Result<()> {
        nix::sys::termios::tcflush(&self.slave, nix::sys::termios::FlushArg::TCIFLUSH)
            .map_err(io::Error::from)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn bytes_cross_both_ways() {
        let mut pty = Pty::open().unwrap();
        let mut port = serial2::SerialPort::open(pty.path(), 115_200).unwrap();
        port.set_read_timeout(Duration::from_secs(5)).unwrap();
        pty.write_all(&[0x00, 0xff, 0x0d, 0x0a, 0x11]).unwrap();
        let mut got = [0u8; 5];
        port.read_exact(&mut got).unwrap();
        assert_eq!(
            got,
            [0x00, 0xff, 0x0d, 0x0a, 0x11],
            "raw: no byte translated"
        );
        port.write_all(&[0x42, 0x0d]).unwrap();
        let mut buf = [0u8; 8];
        let mut n = 0;
        while n < 2 {
            n += pty
                .read_timeout(&mut buf[n..], Duration::from_secs(5))
                .unwrap();
        }
        assert_eq!(&buf[..2], &[0x42, 0x0d]);
        assert_eq!(
            pty.read_timeout(&mut buf, Duration::from_millis(10))
                .unwrap(),
            0
        );
    }
}
