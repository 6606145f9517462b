/// @file Lib3mfPackage.h
/// @brief One named mesh object in a new 3MF model, written through lib3mf to a file (the 3MF
/// mesh writer and the beam-lattice frame writer share it).
#pragma once

#include <Model/COM/NMR_DLLInterfaces.h>

#include <array>
#include <memory>
#include <string>
#include <utility>
#include <vector>

namespace voxlat {

/// Releases a lib3mf object when it goes out of scope.
struct Lib3mfReleaser {
    void operator()(NMR::PLib3MFBase* p) const
    {
        if (p) NMR::lib3mf_release(p);
    }
};
using Lib3mfHandle = std::unique_ptr<NMR::PLib3MFBase, Lib3mfReleaser>;

/// A 3MF model in millimetres with the given metadata and one mesh object named after the file's
/// stem. The caller fills object(); write() adds the build item, stamps fixed UUIDs (lib3mf's
/// are random, and the same content must give the same bytes) and writes the package to the
/// path through AtomicFile. Every lib3mf failure throws std::runtime_error naming the path.
class Lib3mfPackage {
public:
    Lib3mfPackage(std::string path, const std::vector<std::pair<std::string, std::string>>& metadata);

    /// The mesh object to fill with vertices, triangles or beams.
    NMR::PLib3MFModelMeshObject* object() const { return mObject.get(); }

    /// Throws unless @a result is LIB3MF_OK, with lib3mf's message from @a owner and @a what failed.
    void check(LIB3MFRESULT result, NMR::PLib3MFBase* owner, const std::string& what) const;

    /// Adds the build item, sets the object's, the build's and the item's UUIDs (in that order)
    /// and writes the package.
    void write(const std::array<std::string, 3>& uuids) const;

private:
    std::string mPath;
    Lib3mfHandle mModel;
    Lib3mfHandle mObject;
};

}  // namespace voxlat
