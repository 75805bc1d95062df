//! The files commands read and write, checked before the network is touched, and named in
//! every error. `-` stands for stdin where a file is read, and for stdout where one is written.

use std::io;
use std::path::{Path, PathBuf};

use crate::outcome::Failure;

/// `true` for the name that means stdin or stdout.
pub(crate) fn is_std(path: &Path) -> bool {
    path.as_os_str() == "-"
}

/// What went wrong with a file, in words (the operating system's, without its error number).
pub(crate) fn reason(error: &io::Error) -> String {
    if error.get_ref().is_some() {
        // Worded here already.
        return error.to_string();
    }
    match error.kind() {
        io::ErrorKind::NotFound => "no such file or directory".into(),
        io::ErrorKind::PermissionDenied => "permission denied".into(),
        io::ErrorKind::AlreadyExists => "the file exists (it is never overwritten; remove it or name another)".into(),
        io::ErrorKind::IsADirectory => "is a directory (name a file)".into(),
        io::ErrorKind::NotADirectory => "a part of the path is not a directory".into(),
        io::ErrorKind::StorageFull => "no space left on the device".into(),
        io::ErrorKind::ReadOnlyFilesystem => "the file system is read-only".into(),
        _ => error.to_string(),
    }
}

/// `true` when `path` names something that is neither a regular file nor a directory (a FIFO,
/// a character device such as /dev/null, a socket), after following links. Data for such a
/// file is written through to it: it is never replaced by a file of the same name.
pub(crate) async fn is_special(path: &Path) -> bool {
    tokio::fs::metadata(path).await.is_ok_and(|meta| !meta.is_file() && !meta.is_dir())
}

/// Writes `data` through to the special file `path` (see [`is_special`]): opened only once the
/// data is here, so that a FIFO's reader is not held waiting for the network.
pub(crate) async fn write_through(path: &Path, data: &[u8]) -> Result<(), Failure> {
    use tokio::io::AsyncWriteExt as _;
    let mut file = tokio::fs::OpenOptions::new().write(true).open(path).await.map_err(|e| Failure::file(path, e))?;
    file.write_all(data).await.map_err(|e| Failure::file(path, e))?;
    file.flush().await.map_err(|e| Failure::file(path, e))
}

/// The whole of `path` (stdin for `-`); a directory is refused as such.
pub(crate) async fn read_all(path: &Path) -> Result<Vec<u8>, Failure> {
    if is_std(path) {
        let mut data = Vec::new();
        tokio::io::AsyncReadExt::read_to_end(&mut tokio::io::stdin(), &mut data)
            .await
            .map_err(|e| Failure::file(path, e))?;
        return Ok(data);
    }
    refuse_directory(path).await?;
    tokio::fs::read(path).await.map_err(|e| Failure::file(path, e))
}

/// `path` opened for reading (not a directory), with its size.
pub(crate) async fn open(path: &Path) -> Result<(tokio::fs::File, u64), Failure> {
    refuse_directory(path).await?;
    let file = tokio::fs::File::open(path).await.map_err(|e| Failure::file(path, e))?;
    let size = file.metadata().await.map_err(|e| Failure::file(path, e))?.len();
    Ok((file, size))
}

async fn refuse_directory(path: &Path) -> Result<(), Failure> {
    match tokio::fs::metadata(path).await {
        Ok(meta) if meta.is_dir() => Err(Failure::file(path, io::ErrorKind::IsADirectory.into())),
        Ok(_) => Ok(()),
        Err(error) => Err(Failure::file(path, error)),
    }
}

/// Checks that files can be created where `path` points: in it if it is a directory, else
/// beside it (its directory must exist and take a new file). A probe file is made and
/// removed; an existing `path` is no error here (callers that never overwrite check that).
pub(crate) async fn check_writable(path: &Path) -> Result<(), Failure> {
    let dir = match tokio::fs::metadata(path).await {
        Ok(meta) if meta.is_dir() => path.to_path_buf(),
        _ => match path.parent() {
            Some(parent) if !parent.as_os_str().is_empty() => parent.to_path_buf(),
            _ => PathBuf::from("."),
        },
    };
    let meta = tokio::fs::metadata(&dir).await.map_err(|e| Failure::file(&dir, e))?;
    if !meta.is_dir() {
        return Err(Failure::file(&dir, io::ErrorKind::NotADirectory.into()));
    }
    let probe = dir.join(format!(".lcc-stream-probe-{}", std::process::id()));
    match tokio::fs::OpenOptions::new().write(true).create_new(true).open(&probe).await {
        Ok(file) => {
            drop(file);
            let _ = tokio::fs::remove_file(&probe).await;
            Ok(())
        }
        Err(error) => Err(Failure::file(&dir, error)),
    }
}
