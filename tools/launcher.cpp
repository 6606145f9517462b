// The `voxlat` command: sets the huge-page tunable, then runs the engine program
// (`voxlat-engine`, next to this file) with the same arguments.
//
// Why a separate small program: glibc reads its malloc tunables only at start-up, so the engine
// used to execute itself a second time to get huge pages, and loading it (OpenVDB alone brings
// about 70 000 relocations) costs 70-130 ms each time. This launcher links nothing but libc and
// starts in about a millisecond, so the engine is loaded once. The engine still asks for huge
// pages itself when it is run directly.
#include "tools/HugePages.h"

#include <unistd.h>

#include <cerrno>
#include <climits>
#include <cstdio>
#include <cstring>
#include <string>

int main(int, char** argv)
{
    char self[PATH_MAX];
    const ssize_t length = ::readlink("/proc/self/exe", self, sizeof(self) - 1);
    std::string engine = "voxlat-engine";
    if (length > 0) {
        self[length] = '\0';
        const char* slash = std::strrchr(self, '/');
        engine = std::string(self, slash ? std::size_t(slash - self) + 1 : 0) + engine;
    }
    std::string previous;
    bool hadPrevious = false;
    voxlat::requestHugePages(previous, hadPrevious);
    ::execv(engine.c_str(), argv);
    std::fprintf(stderr,
                 "voxlat: cannot run the engine %s: %s (reinstall voxlat: the engine belongs next to this file)\n",
                 engine.c_str(), std::strerror(errno));
    return 127;
}
