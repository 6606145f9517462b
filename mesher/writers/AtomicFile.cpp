#include "mesher/writers/AtomicFile.h"

#include <fcntl.h>
#include <signal.h>
#include <sys/stat.h>
#include <unistd.h>

#include <ext/stdio_filebuf.h>

#include <algorithm>
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
    mBuffer = std::make_unique<__gnu_cxx::stdio_filebuf<char>>(fd, std::ios::out | std::ios::binary, 1 << 16);
    mStream.rdbuf(mBuffer.get());
}

AtomicFile::~AtomicFile()
{
    if (!mCommitted) discard();
}

bool AtomicFile::close() noexcept
{
    auto* buffer = static_cast<__gnu_cxx::stdio_filebuf<char>*>(mBuffer.get());
    if (!buffer || !buffer->is_open()) return true;
    return buffer->close() != nullptr;
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
    mStream.flush();
    // A failed write anywhere earlier (disk full, ...) leaves the stream bad; check before the
    // rename so a truncated file never replaces a good one.
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
