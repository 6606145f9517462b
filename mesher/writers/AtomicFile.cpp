#include "mesher/writers/AtomicFile.h"

#include <unistd.h>

#include <array>
#include <atomic>
#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <filesystem>
#include <stdexcept>
#include <utility>

namespace voxlat {

namespace {

std::string reason()
{
    return errno != 0 ? std::string(": ") + std::strerror(errno) : std::string();
}

/// Registered temporaries: C strings owned by the slots (malloc'd), null where free. A slot is
/// claimed and released with atomic exchanges, so a signal handler may read them at any time.
constexpr std::size_t kTemporarySlots = 4096;
std::array<std::atomic<char*>, kTemporarySlots> gTemporaries{};

}  // namespace

void registerTemporary(const std::string& path)
{
    char* copy = strdup(path.c_str());
    if (!copy) return;
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
        if (held && path == held && slot.compare_exchange_strong(held, nullptr)) {
            std::free(held);
            return;
        }
    }
}

void removeTemporaries() noexcept
{
    for (auto& slot : gTemporaries)
        if (const char* held = slot.load()) ::unlink(held);
}

AtomicFile::AtomicFile(std::string path)
    : mPath(std::move(path)), mTempPath(mPath + ".tmp-" + std::to_string(::getpid()))
{
    errno = 0;
    registerTemporary(mTempPath);
    mStream.open(mTempPath, std::ios::out | std::ios::binary | std::ios::trunc);
    if (!mStream) {
        unregisterTemporary(mTempPath);
        throw OutputError("cannot open '" + mTempPath + "' to write '" + mPath + "'" + reason());
    }
}

AtomicFile::~AtomicFile()
{
    if (!mCommitted) discard();
}

void AtomicFile::discard() noexcept
{
    if (mStream.is_open()) mStream.close();
    std::remove(mTempPath.c_str());
    unregisterTemporary(mTempPath);
}

void AtomicFile::commit()
{
    if (mCommitted) return;
    errno = 0;
    mStream.flush();
    // A failed write anywhere earlier (disk full, ...) leaves the stream bad; check before the
    // rename so a truncated file never replaces a good one.
    const bool written = bool(mStream);
    mStream.close();
    if (!written || mStream.fail()) {
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
}

OutputTransaction::OutputTransaction() : mOuter(tCurrentTransaction)
{
    tCurrentTransaction = this;
}

OutputTransaction::~OutputTransaction()
{
    tCurrentTransaction = mOuter;
    if (mCommitted) return;
    for (const Rename& r : mRenames) {
        std::error_code ec;
        if (r.folder)
            std::filesystem::remove_all(r.temp, ec);
        else
            std::filesystem::remove(r.temp, ec);
        unregisterTemporary(r.temp);
    }
}

OutputTransaction* OutputTransaction::current()
{
    return tCurrentTransaction;
}

void OutputTransaction::add(std::string temp, std::string path, bool folder)
{
    mRenames.push_back({std::move(temp), std::move(path), folder});
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
