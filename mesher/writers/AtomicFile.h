/// @file AtomicFile.h
/// @brief Write-to-temporary-then-rename, so a reader never sees a half-written output file.
#pragma once

#include <functional>
#include <memory>
#include <ostream>
#include <stdexcept>
#include <streambuf>
#include <string>
#include <vector>

namespace voxlat {

/// Writing an output failed: the message names the file and the system's reason (disk full,
/// read-only, no permission). The command line exits 3 on it (a job that cannot run).
class OutputError : public std::runtime_error {
public:
    using std::runtime_error::runtime_error;
};

/// The temporary files and folders that exist now (AtomicFile's and the slice folders', until
/// renamed or removed), so that a process ended by a signal leaves none: the command line's
/// handler calls removeTemporaries(). A @a folder is removed with what it holds.
void registerTemporary(const std::string& path, bool folder = false);
void unregisterTemporary(const std::string& path);
/// Removes every registered temporary file and folder (a folder's files and subfolders first).
/// Async-signal-safe: atomic loads and system calls only (open, getdents64, unlinkat, close).
void removeTemporaries() noexcept;

/// What a long write calls between chunks (at most kWriteChunkBytes apart, and in the loops that
/// prepare the bytes) to learn whether to stop: it throws (the job's Cancelled) to stop, and the
/// write's temporary file is then removed, the old file kept. The job passes its own to the
/// OutputTransaction it opens; every AtomicFile created while that transaction is open uses it.
using WriteInterrupter = std::function<void()>;
constexpr std::size_t kWriteChunkBytes = std::size_t(1) << 16;

/// Calls the interrupter of the OutputTransaction open on this thread, if any (for the loops that
/// prepare a file's bytes before they reach its stream: lib3mf's packing, OpenMesh's mesh).
void checkWriteInterrupt();

/// A fresh temporary name beside @a path: "<path>.tmp-<pid>-<n>", n counted per process, so two
/// writers of one path (two threads, two processes) never share one.
std::string temporaryName(const std::string& path);

/// Temporaries "<path>.tmp-<pid>[-<n>]" beside @a path left by a process that no longer runs (a
/// run killed by SIGKILL or a power cut): the caller names them (they are never reused or removed
/// silently; a new run's temporary has a name of its own).
std::vector<std::string> staleTemporaries(const std::string& path);

/// A binary output file that appears at its final path only once it is complete.
///
/// The data goes to a temporary file "<path>.tmp-<pid>-<n>" in the same directory, created
/// exclusively (O_CREAT | O_EXCL | O_NOFOLLOW: a file or symbolic link planted at that name is
/// refused, never followed or truncated) and unique per writer; commit() flushes and closes it and
/// renames it onto @a path, atomically replacing any existing file. If the object is destroyed
/// without a successful commit() (an exception, an early return), the temporary file is removed
/// and @a path is left untouched.
class AtomicFile {
public:
    /// Opens the temporary file. Throws OutputError naming @a path and the reason if it cannot.
    explicit AtomicFile(std::string path);
    ~AtomicFile();

    AtomicFile(const AtomicFile&) = delete;
    AtomicFile& operator=(const AtomicFile&) = delete;

    /// The stream to write the content to (binary mode). Its bytes reach the file in chunks of
    /// kWriteChunkBytes; before each the interrupter is called, and an exception it throws leaves
    /// the stream's write (the stream throws on badbit) and, through the caller, the writer.
    std::ostream& stream() { return mStream; }
    /// The interrupter this file's chunks check (the open transaction's when it was created).
    const WriteInterrupter& interrupter() const { return mInterrupter; }

    /// The final path.
    const std::string& path() const { return mPath; }
    /// Where the data is written until commit().
    const std::string& tempPath() const { return mTempPath; }
    bool committed() const { return mCommitted; }

    /// Flushes, closes and renames the temporary file onto path(). Throws OutputError
    /// naming path() and the reason if any step fails (the temporary file is then removed).
    void commit();

private:
    void discard() noexcept;
    bool close() noexcept;

    std::string mPath;
    std::string mTempPath;
    WriteInterrupter mInterrupter;
    std::unique_ptr<std::streambuf> mBuffer;
    std::ostream mStream{nullptr};
    bool mCommitted = false;
};

/// Makes a job's outputs appear all together or not at all.
///
/// While an OutputTransaction is open on a thread, AtomicFile::commit() (and the slice folders'
/// finish()) on that thread complete and close their temporary files but leave the renames to
/// commit(), which performs them in order once every output is written. Destroyed without
/// commit() (a later output failed, a cancel), it removes every temporary it holds, so a job that
/// fails half-way leaves the output folder as it was.
class OutputTransaction {
public:
    /// @a interrupter: what the files written under this transaction check between chunks (none:
    /// the enclosing transaction's, if any).
    explicit OutputTransaction(WriteInterrupter interrupter = {});
    ~OutputTransaction();
    OutputTransaction(const OutputTransaction&) = delete;
    OutputTransaction& operator=(const OutputTransaction&) = delete;

    /// The transaction open on this thread, or nullptr.
    static OutputTransaction* current();

    /// Holds back the rename of @a temp onto @a path (a file, or a folder when @a folder: an
    /// empty folder at @a path is replaced).
    void add(std::string temp, std::string path, bool folder);
    /// Drops every held-back rename onto @a path and removes its temporary: a file written ahead
    /// of its turn (a mesh measured as it is written) that is to be written again.
    void withdraw(const std::string& path);

    /// Performs every held-back rename. Throws OutputError naming the path if one fails.
    void commit();

    const WriteInterrupter& interrupter() const { return mInterrupter; }

private:
    struct Rename {
        std::string temp, path;
        bool folder;
    };
    std::vector<Rename> mRenames;
    OutputTransaction* mOuter;
    WriteInterrupter mInterrupter;
    bool mCommitted = false;
};

}  // namespace voxlat
