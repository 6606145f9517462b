#include "mesher/writers/AtomicFile.h"

#include "mesher/writers/DirectWrites.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <sys/syscall.h>
#include <unistd.h>

#include <algorithm>
#include <array>
#include <atomic>
#include <cerrno>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <thread>
#include <utility>

namespace voxlat {

namespace {

std::string reason()
{
    return errno != 0 ? std::string(": ") + std::strerror(errno) : std::string();
}

/// Registered temporaries: C strings owned by the slots (malloc'd), null where free, each a kind
/// letter ('f' a file, 'd' a folder) and the path. A slot is claimed and released with atomic
/// exchanges, so a signal handler may read them at any time.
constexpr std::size_t kTemporarySlots = 4096;
std::array<std::atomic<char*>, kTemporarySlots> gTemporaries{};

/// getdents64's record (the kernel's struct linux_dirent64).
struct DirectoryEntry {
    std::uint64_t inode;
    std::int64_t offset;
    unsigned short length;
    unsigned char type;
    char name[1];
};

/// Removes @a name under the folder @a parent, a folder with what it holds. System calls only
/// (async-signal-safe); a folder's listing is read again until a pass removes nothing, since
/// removing entries while listing them may skip some.
void removeTree(int parent, const char* name, int depth) noexcept
{
    if (::unlinkat(parent, name, 0) == 0 || (errno != EISDIR && errno != EPERM)) return;
    if (depth < 16) {
        const int fd = ::openat(parent, name, O_RDONLY | O_DIRECTORY | O_NOFOLLOW | O_CLOEXEC);
        if (fd >= 0) {
            alignas(8) char listing[4096];
            for (int pass = 0; pass < 64; ++pass) {
                bool removed = false;
                ::lseek(fd, 0, SEEK_SET);
                for (long n; (n = ::syscall(SYS_getdents64, fd, listing, sizeof listing)) > 0;)
                    for (long at = 0; at < n;) {
                        const auto* entry = reinterpret_cast<const DirectoryEntry*>(listing + at);
                        at += entry->length;
                        const char* child = entry->name;
                        if (child[0] == '.' && (child[1] == 0 || (child[1] == '.' && child[2] == 0))) continue;
                        removeTree(fd, child, depth + 1);
                        removed = true;
                    }
                if (!removed) break;
            }
            ::close(fd);
        }
    }
    ::unlinkat(parent, name, AT_REMOVEDIR);
}

/// A test hook: VOXLAT_TEST_WRITE_DELAY_MS slows every chunk (and the last bytes) of every output
/// file by that many milliseconds, so a test can signal a run while it writes (tests/test_cli.cpp). 0 when unset.
int writeDelayMs()
{
    static const int delay = [] {
        const char* value = std::getenv("VOXLAT_TEST_WRITE_DELAY_MS");
        return value ? std::max(0, std::atoi(value)) : 0;
    }();
    return delay;
}

/// Bytes of a file written through the page cache before the rest goes direct (DirectWrites): a
/// small file (a report, a recipe, a preview) never starts a thread.
constexpr off_t kDirectFrom = off_t(8) << 20;

/// The temporary's stream buffer: kWriteChunkBytes of buffer, written with write(2), the
/// interrupter called before each chunk. A failed write (disk full) is kept (its errno) and the
/// bytes after it dropped, so the stream goes bad only by an exception (the interrupter's), which
/// the stream passes on; the failure is found by close(). Past kDirectFrom bytes written in order
/// from the start (no seek yet), the rest goes past the page cache (DirectWrites); a seek or
/// close() first waits for those writes.
class ChunkedFileBuffer : public std::streambuf {
public:
    ChunkedFileBuffer(int fd, WriteInterrupter interrupter)
        : mFd(fd), mInterrupter(std::move(interrupter)), mBytes(kWriteChunkBytes)
    {
        setp(mBytes.data(), mBytes.data() + mBytes.size());
    }
    ~ChunkedFileBuffer() override { close(); }

    /// Writes what is buffered (no interrupter: the caller commits) and closes the file. False
    /// (errno set) if any write or the close failed.
    bool close() noexcept
    {
        if (mFd < 0) return mError == 0;
        put(pbase(), std::size_t(pptr() - pbase()));
        setp(mBytes.data(), mBytes.data() + mBytes.size());
        endDirect();
        if (::close(mFd) != 0 && mError == 0) mError = errno;
        mFd = -1;
        errno = mError;
        return mError == 0;
    }

protected:
    int_type overflow(int_type c) override
    {
        flushChunk();
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            *pptr() = traits_type::to_char_type(c);
            pbump(1);
        }
        return traits_type::not_eof(c);
    }

    std::streamsize xsputn(const char* s, std::streamsize n) override
    {
        const auto chunk = std::streamsize(mBytes.size());
        for (std::streamsize left = n; left > 0;) {
            const std::streamsize room = epptr() - pptr();
            if (room == 0) {
                flushChunk();
                continue;
            }
            if (pptr() == pbase() && left >= chunk) {
                // Nothing buffered and a whole chunk to go: written from the caller's bytes (a
                // streamed STL passes hundreds of MB), the same chunks and interrupter calls as
                // through the buffer, without copying them into it first.
                if (mInterrupter) mInterrupter();
                put(s, std::size_t(chunk));
                s += chunk;
                left -= chunk;
                continue;
            }
            const std::streamsize take = std::min(room, left);
            std::memcpy(pptr(), s, std::size_t(take));
            pbump(int(take));
            s += take;
            left -= take;
        }
        return n;
    }

    int sync() override
    {
        flushChunk();
        return 0;
    }

    /// tellp() and seekp() (the streamed STL writes its triangle count into its header last):
    /// what is buffered is written first, then the file's offset is moved.
    pos_type seekoff(off_type offset, std::ios_base::seekdir dir, std::ios_base::openmode) override
    {
        put(pbase(), std::size_t(pptr() - pbase()));
        setp(mBytes.data(), mBytes.data() + mBytes.size());
        endDirect();
        mSeeked = true;
        if (mError != 0 || mFd < 0) return pos_type(off_type(-1));
        const int whence = dir == std::ios_base::beg ? SEEK_SET : dir == std::ios_base::cur ? SEEK_CUR : SEEK_END;
        const off_t at = ::lseek(mFd, off_t(offset), whence);
        return at < 0 ? pos_type(off_type(-1)) : pos_type(off_type(at));
    }
    pos_type seekpos(pos_type position, std::ios_base::openmode which) override
    {
        return seekoff(off_type(position), std::ios_base::beg, which);
    }

private:
    void flushChunk()
    {
        const std::size_t n = std::size_t(pptr() - pbase());
        if (n == 0) return;
        if (mInterrupter) mInterrupter();  // throws to stop the write
        put(pbase(), n);
        setp(mBytes.data(), mBytes.data() + mBytes.size());
    }

    void put(const char* p, std::size_t n) noexcept
    {
        if (const int delay = writeDelayMs(); delay > 0 && n > 0)
            std::this_thread::sleep_for(std::chrono::milliseconds(delay));
        if (!mDirect && !mSeeked && mWritten >= kDirectFrom && mError == 0 && mFd >= 0) {
            // Up to a block boundary through the page cache, the rest direct.
            const auto pad = std::size_t((off_t(DirectWrites::kAlign) - mWritten % off_t(DirectWrites::kAlign)) %
                                         off_t(DirectWrites::kAlign));
            const std::size_t head = std::min(pad, n);
            writeBuffered(p, head);
            p += head;
            n -= head;
            if (mWritten % off_t(DirectWrites::kAlign) == 0) {
                mDirect = DirectWrites::open(mFd, mWritten);
                if (!mDirect) mSeeked = true;  // not again
            }
        }
        if (mDirect) {
            if (mError == 0) mDirect->append(p, n);
            mWritten += off_t(n);
            return;
        }
        writeBuffered(p, n);
    }

    void writeBuffered(const char* p, std::size_t n) noexcept
    {
        while (n > 0 && mError == 0 && mFd >= 0) {
            const ssize_t written = ::write(mFd, p, n);
            if (written < 0) {
                if (errno != EINTR) mError = errno;
                continue;
            }
            p += written;
            n -= std::size_t(written);
            mWritten += off_t(written);
        }
    }

    /// Waits for the direct writes and puts the descriptor's offset at the end of what was written.
    void endDirect() noexcept
    {
        if (!mDirect) return;
        const int error = mDirect->finish();
        mDirect.reset();
        if (error != 0 && mError == 0) mError = error;
        if (mFd >= 0 && ::lseek(mFd, mWritten, SEEK_SET) < 0 && mError == 0) mError = errno;
    }

    int mFd;
    WriteInterrupter mInterrupter;
    std::vector<char> mBytes;
    int mError = 0;
    off_t mWritten = 0;    ///< bytes written in order from the start (until a seek)
    bool mSeeked = false;  ///< seeked once: no direct writes from then on
    std::unique_ptr<DirectWrites> mDirect;
};

}  // namespace

void registerTemporary(const std::string& path, bool folder)
{
    char* copy = static_cast<char*>(std::malloc(path.size() + 2));
    if (!copy) return;
    copy[0] = folder ? 'd' : 'f';
    std::memcpy(copy + 1, path.c_str(), path.size() + 1);
    for (auto& slot : gTemporaries) {
        char* expected = nullptr;
        if (slot.compare_exchange_strong(expected, copy)) return;
    }
    std::free(copy);  // more open temporaries than slots: this one is not removed by a signal
}

void unregisterTemporary(const std::string& path)
{
    for (auto& slot : gTemporaries) {
        char* held = slot.load();
        if (held && path == held + 1 && slot.compare_exchange_strong(held, nullptr)) {
            std::free(held);
            return;
        }
    }
}

void removeTemporaries() noexcept
{
    // Files first: a file's temporary may sit inside a temporary folder.
    for (const char kind : {'f', 'd'})
        for (auto& slot : gTemporaries)
            if (const char* held = slot.load(); held && held[0] == kind) {
                if (kind == 'f')
                    ::unlink(held + 1);
                else
                    removeTree(AT_FDCWD, held + 1, 0);
            }
}

void checkWriteInterrupt()
{
    if (const OutputTransaction* transaction = OutputTransaction::current())
        if (transaction->interrupter()) transaction->interrupter()();
}

std::string temporaryName(const std::string& path)
{
    static std::atomic<std::uint64_t> counter{0};
    return path + ".tmp-" + std::to_string(::getpid()) + "-" + std::to_string(counter.fetch_add(1));
}

std::vector<std::string> staleTemporaries(const std::string& path)
{
    namespace fs = std::filesystem;
    std::vector<std::string> stale;
    const fs::path p(path);
    const std::string prefix = p.filename().string() + ".tmp-";
    std::error_code ec;
    fs::directory_iterator it(p.parent_path().empty() ? fs::path(".") : p.parent_path(), ec), end;
    for (; !ec && it != end; it.increment(ec)) {
        const std::string name = it->path().filename().string();
        if (name.compare(0, prefix.size(), prefix) != 0) continue;
        const std::string rest = name.substr(prefix.size());
        const std::size_t digits = rest.find_first_not_of("0123456789");
        if (digits == 0 || (digits != std::string::npos && rest[digits] != '-')) continue;
        const long pid = std::strtol(rest.substr(0, digits).c_str(), nullptr, 10);
        // A process that still runs (this one, or another writing the same folder) owns its own.
        if (pid > 0 && (::kill(pid_t(pid), 0) == 0 || errno == EPERM)) continue;
        stale.push_back(it->path().string());
    }
    std::sort(stale.begin(), stale.end());
    return stale;
}

AtomicFile::AtomicFile(std::string path) : mPath(std::move(path))
{
    // A fresh name each time; O_EXCL | O_NOFOLLOW: never a file or link someone put there.
    int fd = -1;
    for (int attempt = 0; attempt < 100 && fd < 0; ++attempt) {
        mTempPath = temporaryName(mPath);
        errno = 0;
        fd = ::open(mTempPath.c_str(), O_WRONLY | O_CREAT | O_EXCL | O_NOFOLLOW | O_CLOEXEC, 0666);
        if (fd < 0 && errno != EEXIST) break;
    }
    if (fd < 0) throw OutputError("cannot create '" + mTempPath + "' to write '" + mPath + "'" + reason());
    registerTemporary(mTempPath);
    if (const OutputTransaction* transaction = OutputTransaction::current()) mInterrupter = transaction->interrupter();
    mBuffer = std::make_unique<ChunkedFileBuffer>(fd, mInterrupter);
    mStream.rdbuf(mBuffer.get());
    // The buffer fails only by throwing (the interrupter's exception), and that must leave the
    // writer: the stream passes it on.
    mStream.exceptions(std::ios::badbit);
}

AtomicFile::~AtomicFile()
{
    if (!mCommitted) discard();
}

bool AtomicFile::close() noexcept
{
    auto* buffer = static_cast<ChunkedFileBuffer*>(mBuffer.get());
    return !buffer || buffer->close();
}

void AtomicFile::discard() noexcept
{
    close();
    std::remove(mTempPath.c_str());
    unregisterTemporary(mTempPath);
}

void AtomicFile::commit()
{
    if (mCommitted) return;
    errno = 0;
    // A failed write anywhere earlier (disk full, ...) is kept by the buffer and found by
    // close(); checked before the rename so a truncated file never replaces a good one.
    const bool written = bool(mStream);
    if (!close() || !written) {
        const std::string why = reason();
        discard();
        throw OutputError("failed to write '" + mPath + "'" + why);
    }
    if (OutputTransaction* transaction = OutputTransaction::current()) {
        transaction->add(mTempPath, mPath, false);
        mCommitted = true;
        return;
    }
    errno = 0;
    if (std::rename(mTempPath.c_str(), mPath.c_str()) != 0) {
        const std::string why = reason();
        discard();
        throw OutputError("failed to rename '" + mTempPath + "' onto '" + mPath + "'" + why);
    }
    unregisterTemporary(mTempPath);
    mCommitted = true;
}

namespace {
thread_local OutputTransaction* tCurrentTransaction = nullptr;

/// Removes a transaction's temporary file or folder (with what it holds) that is not to be renamed.
void removeHeldTemporary(const std::string& temp, bool folder)
{
    std::error_code ec;
    if (folder)
        std::filesystem::remove_all(temp, ec);
    else
        std::filesystem::remove(temp, ec);
    unregisterTemporary(temp);
}
}  // namespace

OutputTransaction::OutputTransaction(WriteInterrupter interrupter)
    : mOuter(tCurrentTransaction), mInterrupter(std::move(interrupter))
{
    if (!mInterrupter && mOuter) mInterrupter = mOuter->mInterrupter;
    tCurrentTransaction = this;
}

OutputTransaction::~OutputTransaction()
{
    tCurrentTransaction = mOuter;
    if (mCommitted) return;
    for (const Rename& r : mRenames) removeHeldTemporary(r.temp, r.folder);
}

OutputTransaction* OutputTransaction::current()
{
    return tCurrentTransaction;
}

void OutputTransaction::add(std::string temp, std::string path, bool folder)
{
    mRenames.push_back({std::move(temp), std::move(path), folder});
}

void OutputTransaction::withdraw(const std::string& path)
{
    std::erase_if(mRenames, [&](const Rename& r) {
        if (r.path != path) return false;
        removeHeldTemporary(r.temp, r.folder);
        return true;
    });
}

void OutputTransaction::commit()
{
    // Leave the thread first: a rename that throws must not leave a finished transaction current.
    tCurrentTransaction = mOuter;
    for (std::size_t i = 0; i < mRenames.size(); ++i) {
        const Rename& r = mRenames[i];
        std::error_code ec;
        if (r.folder) std::filesystem::remove(r.path, ec);  // an empty folder only (checked when opened)
        errno = 0;
        if (std::rename(r.temp.c_str(), r.path.c_str()) != 0) {
            const std::string message = "failed to rename '" + r.temp + "' onto '" + r.path + "'" + reason();
            // The renamed ones stay; the destructor removes the temporaries still held.
            mRenames.erase(mRenames.begin(), mRenames.begin() + std::ptrdiff_t(i));
            throw OutputError(message);
        }
        unregisterTemporary(r.temp);
    }
    mCommitted = true;
}

}  // namespace voxlat
