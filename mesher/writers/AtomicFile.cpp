#include "mesher/writers/AtomicFile.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <utility>

namespace voxlat {

namespace {

std::string reason()
{
    return errno != 0 ? std::string(": ") + std::strerror(errno) : std::string();
}

}  // namespace

AtomicFile::AtomicFile(std::string path)
    : mPath(std::move(path)), mTempPath(mPath + ".tmp-" + std::to_string(::getpid()))
{
    errno = 0;
    mStream.open(mTempPath, std::ios::out | std::ios::binary | std::ios::trunc);
    if (!mStream) throw std::runtime_error("cannot open '" + mTempPath + "' to write '" + mPath + "'" + reason());
}

AtomicFile::~AtomicFile()
{
    if (!mCommitted) discard();
}

void AtomicFile::discard() noexcept
{
    if (mStream.is_open()) mStream.close();
    std::remove(mTempPath.c_str());
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
        throw std::runtime_error("failed to write '" + mPath + "'" + why);
    }
    errno = 0;
    if (std::rename(mTempPath.c_str(), mPath.c_str()) != 0) {
        const std::string why = reason();
        discard();
        throw std::runtime_error("failed to rename '" + mTempPath + "' onto '" + mPath + "'" + why);
    }
    mCommitted = true;
}

}  // namespace voxlat
