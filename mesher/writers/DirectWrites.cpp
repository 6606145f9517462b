#include "mesher/writers/DirectWrites.h"

#include <fcntl.h>
#include <unistd.h>

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cstring>
#include <new>
#include <string>

namespace voxlat {

std::unique_ptr<DirectWrites> DirectWrites::open(int bufferedFd, off_t start)
{
    if (bufferedFd < 0 || start % off_t(kAlign) != 0) return nullptr;
    // A description of its own (a dup would share the buffered one's flags).
    const std::string self = "/proc/self/fd/" + std::to_string(bufferedFd);
    const int fd = ::open(self.c_str(), O_WRONLY | O_DIRECT | O_CLOEXEC);
    if (fd < 0) return nullptr;
    try {
        return std::unique_ptr<DirectWrites>(new DirectWrites(bufferedFd, fd, start));
    } catch (...) {
        ::close(fd);  // no memory or no thread: the caller writes through the page cache
        return nullptr;
    }
}

DirectWrites::DirectWrites(int bufferedFd, int directFd, off_t start)
    : mBufferedFd(bufferedFd), mDirectFd(directFd), mEnd(start), mFilling(0), mBuffers(kBuffers)
{
    const auto release = [this] {
        for (Buffer& b : mBuffers) std::free(b.bytes);
    };
    for (Buffer& b : mBuffers)
        if (!(b.bytes = static_cast<char*>(std::aligned_alloc(kAlign, kBufferBytes)))) {
            release();
            throw std::bad_alloc();
        }
    mBuffers[0].at = start;
    try {
        mThread = std::thread([this] { run(); });
    } catch (...) {
        release();
        throw;
    }
}

DirectWrites::~DirectWrites()
{
    finish();
    for (Buffer& b : mBuffers) std::free(b.bytes);
}

int DirectWrites::writeAt(const char* p, std::size_t n, off_t at, bool direct)
{
    while (n > 0) {
        const bool aligned = direct && n % kAlign == 0 && at % off_t(kAlign) == 0;
        const ssize_t written = ::pwrite(aligned ? mDirectFd : mBufferedFd, p, n, at);
        if (written < 0) {
            if (errno == EINTR) continue;
            if (aligned && errno == EINVAL) {
                // The file system takes no direct writes: the rest buffered.
                direct = false;
                mDirect = false;
                continue;
            }
            return errno;
        }
        if (written == 0) return EIO;
        p += written;
        n -= std::size_t(written);
        at += off_t(written);
    }
    return 0;
}

void DirectWrites::run()
{
    for (;;) {
        std::size_t index;
        {
            std::unique_lock<std::mutex> lock(mMutex);
            mChanged.wait(lock, [&] { return mStop || !mQueue.empty(); });
            if (mQueue.empty()) return;  // stopped with nothing left
            index = mQueue.front();
        }
        Buffer& b = mBuffers[index];
        const int error = writeAt(b.bytes, b.size, b.at, mDirect);
        std::lock_guard<std::mutex> lock(mMutex);
        if (error != 0 && mError == 0) mError = error;
        mQueue.erase(mQueue.begin());
        b.queued = false;
        mChanged.notify_all();
    }
}

void DirectWrites::append(const char* p, std::size_t n)
{
    while (n > 0) {
        Buffer& b = mBuffers[mFilling];
        const std::size_t take = std::min(n, kBufferBytes - b.size);
        std::memcpy(b.bytes + b.size, p, take);
        b.size += take;
        mEnd += off_t(take);
        p += take;
        n -= take;
        if (b.size < kBufferBytes) break;
        // Full: to the writer thread, and the next free buffer filled. With none free (the disk
        // behind), this one is written here, direct too: two writes in flight.
        const std::size_t next = (mFilling + 1) % kBuffers;
        std::unique_lock<std::mutex> lock(mMutex);
        if (mError != 0) {
            b.size = 0;
            b.at = mEnd;
            continue;
        }
        if (mBuffers[next].queued) {
            lock.unlock();
            const int error = writeAt(b.bytes, b.size, b.at, mDirect);
            lock.lock();
            if (error != 0 && mError == 0) mError = error;
            b.size = 0;
            b.at = mEnd;
            continue;
        }
        b.queued = true;
        mQueue.push_back(mFilling);
        mChanged.notify_all();
        mFilling = next;
        mBuffers[next].size = 0;
        mBuffers[next].at = mEnd;
    }
}

int DirectWrites::finish()
{
    if (mThread.joinable()) {
        {
            std::lock_guard<std::mutex> lock(mMutex);
            mStop = true;
            mChanged.notify_all();
        }
        mThread.join();
        // The buffer being filled: its whole blocks direct, the rest through the page cache.
        const Buffer& b = mBuffers[mFilling];
        if (mError == 0 && b.size > 0) {
            const std::size_t whole = b.size / kAlign * kAlign;
            int error = writeAt(b.bytes, whole, b.at, mDirect);
            if (error == 0) error = writeAt(b.bytes + whole, b.size - whole, b.at + off_t(whole), false);
            mError = error;
        }
    }
    if (mDirectFd >= 0) {
        ::close(mDirectFd);
        mDirectFd = -1;
    }
    return mError;
}

}  // namespace voxlat
