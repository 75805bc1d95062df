//! Spaces for a node on a host: [`FileSpace`], a memory space kept in a file (a board's space
//! 0xFD: each write command reaches the file whole, once, at its end, so that the file holds
//! the space as it was before or after every command, even when the program is killed), and
//! [`SharedSpace`], one space for the memory server and the application.

use std::io::{Seek as _, SeekFrom, Write as _};
use std::path::{Path, PathBuf};
use std::sync::{Arc, Mutex, MutexGuard, PoisonError};

use openlcb_node::{MemorySpace, RamSpace, SpaceError};
use openlcb_stream::wire::ErrorCode;

/// The unit of the file a single `write` of changed bytes never crosses.
const PAGE: u32 = 4096;

/// A memory space in a file. Reads come from memory; a write command's bytes reach the file
/// at its [`commit`](MemorySpace::commit) (once per command or transfer): within one 4 KiB
/// page (a Write datagram's) in place, with one `write` the kernel does at once or not at
/// all; anything larger (a Write Stream's) by replacing the file, through `<file>.part` and
/// a rename. A commit that fails puts the space back to what the file holds.
///
/// ```no_run
/// use openlcb_tokio::FileSpace;
/// use openlcb_tokio::openlcb_node::MemoryServer;
///
/// let (config, _new) = FileSpace::open_or_create("board-config.bin", 256)?;
/// let server = MemoryServer::new().with_space(0xFD, config);
/// # Ok::<(), std::io::Error>(())
/// ```
#[derive(Debug)]
pub struct FileSpace {
    path: PathBuf,
    bytes: RamSpace,
    /// The addresses written since the last commit.
    dirty: Option<(u32, u32)>,
}

impl FileSpace {
    /// The space the file at `path` holds (1 byte to 4 GiB), checked writable by saving it
    /// once.
    pub fn open(path: impl AsRef<Path>) -> std::io::Result<FileSpace> {
        let path = path.as_ref();
        let bytes = std::fs::read(path)?;
        if bytes.is_empty() || u32::try_from(bytes.len()).is_err() {
            return Err(std::io::Error::new(std::io::ErrorKind::InvalidData, "a space file holds 1 byte to 4 GiB"));
        }
        save_whole(path, &bytes)?;
        Ok(FileSpace { path: path.to_path_buf(), bytes: RamSpace::from_bytes(bytes), dirty: None })
    }

    /// The space of the file at `path`, or of a new file of `len` zero bytes there; `true`
    /// when it is new (a board then writes its factory defaults).
    pub fn open_or_create(path: impl AsRef<Path>, len: u32) -> std::io::Result<(FileSpace, bool)> {
        let path = path.as_ref();
        let new = !path.exists();
        if new {
            save_whole(path, &vec![0; len as usize])?;
        }
        Ok((FileSpace::open(path)?, new))
    }

    /// The bytes of the space, as reads see them.
    pub fn as_bytes(&self) -> &[u8] {
        self.bytes.as_bytes()
    }
}

impl MemorySpace for FileSpace {
    fn len(&self) -> u32 {
        self.bytes.len()
    }
    fn read_only(&self) -> bool {
        false
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        self.bytes.read(address, buf)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        self.bytes.write(address, data)?;
        let end = address + data.len() as u32;
        self.dirty = Some(self.dirty.map_or((address, end), |(low, high)| (low.min(address), high.max(end))));
        Ok(())
    }
    fn commit(&mut self) -> Result<(), SpaceError> {
        let Some((start, end)) = self.dirty else { return Ok(()) };
        let whole = self.bytes.as_bytes();
        let saved = match whole.get(start as usize..end as usize) {
            Some(changed) if start / PAGE == end.saturating_sub(1) / PAGE => write_in_place(&self.path, start, changed),
            _ => save_whole(&self.path, whole),
        };
        if saved.is_err() {
            // Not saved: the space goes back to what the file holds, so that no read-back
            // takes the failed command for done; a file that cannot be read either keeps the
            // bytes marked for the next commit.
            if let Ok(held) = std::fs::read(&self.path)
                && held.len() == whole.len()
            {
                self.bytes = RamSpace::from_bytes(held);
                self.dirty = None;
            }
            return Err(SpaceError::Failed(ErrorCode::PERMANENT));
        }
        self.dirty = None;
        Ok(())
    }
}

/// A space shared between the memory server and the application: clones are handles to one
/// space, so that the application reads what a tool wrote (a board's settings at Update
/// Complete) and writes its own (a Factory Reset's defaults).
#[derive(Debug)]
pub struct SharedSpace<S>(Arc<Mutex<S>>);

impl<S> Clone for SharedSpace<S> {
    fn clone(&self) -> Self {
        SharedSpace(self.0.clone())
    }
}

impl<S> SharedSpace<S> {
    /// A shared `space`.
    pub fn new(space: S) -> Self {
        SharedSpace(Arc::new(Mutex::new(space)))
    }

    /// The space, locked; one that a panic left behind is used as it is (its bytes are all
    /// there).
    pub fn lock(&self) -> MutexGuard<'_, S> {
        self.0.lock().unwrap_or_else(PoisonError::into_inner)
    }
}

impl<S: MemorySpace> MemorySpace for SharedSpace<S> {
    fn len(&self) -> u32 {
        self.lock().len()
    }
    fn read_only(&self) -> bool {
        self.lock().read_only()
    }
    fn write_only(&self) -> bool {
        self.lock().write_only()
    }
    fn read(&mut self, address: u32, buf: &mut [u8]) -> Result<usize, SpaceError> {
        self.lock().read(address, buf)
    }
    fn write(&mut self, address: u32, data: &[u8]) -> Result<(), SpaceError> {
        self.lock().write(address, data)
    }
    fn commit(&mut self) -> Result<(), SpaceError> {
        self.lock().commit()
    }
    fn write_window(&self) -> Option<u16> {
        self.lock().write_window()
    }
    fn complete(&mut self, len: u32) -> Result<(), SpaceError> {
        self.lock().complete(len)
    }
    fn discard(&mut self) {
        self.lock().discard();
    }
}

/// Writes `bytes` over the same range of the file at `path`, in one `write`.
fn write_in_place(path: &Path, start: u32, bytes: &[u8]) -> std::io::Result<()> {
    let mut file = std::fs::OpenOptions::new().write(true).open(path)?;
    file.seek(SeekFrom::Start(u64::from(start)))?;
    file.write_all(bytes)
}

/// Replaces the file at `path` with `bytes`: through `<path>.part`, synced, then renamed (a
/// file replaced keeps its permissions).
pub(crate) fn save_whole(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let mut part = path.as_os_str().to_owned();
    part.push(".part");
    let part = PathBuf::from(part);
    let written = std::fs::File::create(&part).and_then(|mut file| {
        if let Ok(meta) = std::fs::metadata(path) {
            file.set_permissions(meta.permissions())?;
        }
        file.write_all(bytes)?;
        file.sync_all()?;
        std::fs::rename(&part, path)
    });
    if written.is_err() {
        let _ = std::fs::remove_file(&part);
    }
    written
}

#[cfg(test)]
#[allow(clippy::unwrap_used, clippy::indexing_slicing)] // a test's assertions
mod tests {
    use super::*;

    fn part_path(path: &Path) -> PathBuf {
        let mut name = path.as_os_str().to_owned();
        name.push(".part");
        PathBuf::from(name)
    }

    #[test]
    fn a_file_takes_each_write_command_whole_at_its_commit() {
        let dir = std::env::temp_dir().join(format!("openlcb-file-space-{}", std::process::id()));
        let _ = std::fs::remove_dir_all(&dir);
        std::fs::create_dir_all(&dir).unwrap();
        let path = dir.join("config.bin");
        let (mut space, new) = FileSpace::open_or_create(&path, 3 * PAGE).unwrap();
        assert!(new && std::fs::read(&path).unwrap() == vec![0; 3 * PAGE as usize]);
        // A transfer in pieces across pages: the file keeps the old bytes until its commit.
        for (i, address) in (0..2 * PAGE).step_by(256).enumerate() {
            space.write(address, &[i as u8 + 1; 256]).unwrap();
        }
        assert!(std::fs::read(&path).unwrap().iter().all(|b| *b == 0), "nothing before the commit");
        space.commit().unwrap();
        let file = std::fs::read(&path).unwrap();
        assert_eq!(file[..2 * PAGE as usize], space.as_bytes()[..2 * PAGE as usize]);
        assert!(!part_path(&path).exists());
        // A datagram's bytes within one page: written in place.
        space.write(PAGE * 2 + 10, &[0xAB; 64]).unwrap();
        space.commit().unwrap();
        assert_eq!(std::fs::read(&path).unwrap(), space.as_bytes());
        assert!(space.commit().is_ok(), "nothing left to store");
        assert!(!FileSpace::open_or_create(&path, 1).unwrap().1, "an existing file is not new");
        // A commit that cannot replace the file (a folder stands where its `.part` goes,
        // which even root cannot create as a file) fails, and the space reads as the file
        // still holds it.
        let held = std::fs::read(&path).unwrap();
        std::fs::create_dir(part_path(&path)).unwrap();
        space.write(0, &[0x5A; 2 * PAGE as usize]).unwrap();
        assert!(space.commit().is_err());
        assert_eq!(space.as_bytes(), &held[..], "the failed command is not read back as done");
        assert_eq!(std::fs::read(&path).unwrap(), held);
        std::fs::remove_dir_all(&dir).unwrap();
    }

    #[test]
    fn clones_of_a_shared_space_are_one_space() {
        let mut server = SharedSpace::new(RamSpace::new(16));
        let mut application = server.clone();
        server.write(3, &[7, 8]).unwrap();
        let mut buf = [0; 2];
        application.read(3, &mut buf).unwrap();
        assert_eq!(buf, [7, 8]);
    }
}
