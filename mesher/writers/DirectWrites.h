/// @file DirectWrites.h
/// @brief A file's bulk written past the page cache (O_DIRECT), from a thread of its own.
#pragma once

#include <sys/types.h>
#include <atomic>
#include <condition_variable>
#include <cstddef>
#include <memory>
#include <mutex>
#include <thread>
#include <vector>

namespace voxlat {

/// Appends bytes to a file from offset @a start on (a multiple of kAlign) through a second file
/// description of the same file opened O_DIRECT: the bytes go from a few aligned buffers to the
/// disk, never through the page cache. A streamed 50 mm lattice's STL is 0.8 GB: through the
/// page cache each of its pages is allocated, zeroed by the kernel and copied into (on this
/// project's virtual machine about 1.7 ms per MB on pages fresh to the guest, the job's memory
/// twice over), and it evicts as much of the cache.
///
/// A thread of its own writes each full buffer while the caller fills the next, so the caller
/// waits on the disk only at finish(). When every buffer is still being written (a disk slower
/// than the caller), the caller writes the full one itself, direct as well: two writes in flight.
/// (Through the page cache, as it once did, that write was the slower: on this project's virtual
/// machine 0.34 GB/s buffered against 1.4 GB/s direct for 600 MB, and the acceptance gyroid's
/// mesh-and-STL stage 0.62-0.95 s against 0.56-0.61 s.) A file system that refuses O_DIRECT
/// (EINVAL: tmpfs, some network file systems) gets the rest of the bytes buffered. The file's
/// bytes are the same either way.
class DirectWrites {
public:
    static constexpr std::size_t kAlign = 4096;            ///< offsets, lengths and memory of direct writes
    static constexpr std::size_t kBufferBytes = 4u << 20;  ///< one direct write
    static constexpr std::size_t kBuffers = 4;

    /// Null when the file cannot be opened again O_DIRECT (no /proc, a file system refusing it
    /// at open). @a bufferedFd stays the caller's: never closed here.
    static std::unique_ptr<DirectWrites> open(int bufferedFd, off_t start);
    ~DirectWrites();
    DirectWrites(const DirectWrites&) = delete;
    DirectWrites& operator=(const DirectWrites&) = delete;

    /// Appends @a n bytes after those appended before. After an error, bytes are dropped (finish()
    /// returns the error).
    void append(const char* p, std::size_t n);
    /// Writes what is held (its tail past the last multiple of kAlign through the buffered
    /// descriptor), waits for every write, stops the thread and closes the direct descriptor.
    /// Returns 0, or the errno of the first write that failed. The file's end is then start +
    /// the bytes appended; the buffered descriptor's offset is not moved.
    int finish();

private:
    DirectWrites(int bufferedFd, int directFd, off_t start);
    void run();
    /// Writes @a n bytes at @a at: direct while allowed (falling back on EINVAL), else buffered.
    /// Returns 0 or an errno.
    int writeAt(const char* p, std::size_t n, off_t at, bool direct);

    struct Buffer {
        char* bytes = nullptr;
        std::size_t size = 0;
        off_t at = 0;
        bool queued = false;
    };

    int mBufferedFd;
    int mDirectFd;
    off_t mEnd;            ///< the file offset after the bytes appended so far
    std::size_t mFilling;  ///< the buffer being filled (the caller's)
    std::vector<Buffer> mBuffers;
    std::mutex mMutex;
    std::condition_variable mChanged;
    std::vector<std::size_t> mQueue;  ///< buffers to write, in order (mMutex)
    bool mStop = false;               ///< mMutex
    std::atomic<bool> mDirect{true};  ///< direct writes still allowed
    int mError = 0;                   ///< mMutex
    std::thread mThread;
};

}  // namespace voxlat
