#include "mesher/writers/Lib3mfPackage.h"

#include "mesher/writers/AtomicFile.h"

#include <exception>
#include <filesystem>
#include <stdexcept>

namespace voxlat {

using namespace NMR;

namespace {
/// lib3mf's progress callback: the open transaction's interrupter, its exception kept to be
/// thrown again once lib3mf has unwound (it reports NMR_USERABORTED meanwhile).
bool interruptPacking(int, ProgressIdentifier, void* userData)
{
    try {
        checkWriteInterrupt();
        return true;
    } catch (...) {
        *static_cast<std::exception_ptr*>(userData) = std::current_exception();
        return false;
    }
}
}  // namespace

Lib3mfPackage::Lib3mfPackage(std::string path, const std::vector<std::pair<std::string, std::string>>& metadata)
    : mPath(std::move(path))
{
    PLib3MFModel* model = nullptr;
    check(lib3mf_createmodel(&model), nullptr, "create a model");
    mModel.reset(model);
    check(lib3mf_model_setunit(model, MODELUNIT_MILLIMETER), model, "set the unit");
    for (const auto& [key, value] : metadata)
        check(lib3mf_model_addmetadatautf8(model, key.c_str(), value.c_str()), model, "add the metadata " + key);
    PLib3MFModelMeshObject* object = nullptr;
    check(lib3mf_model_addmeshobject(model, &object), model, "add a mesh object");
    mObject.reset(object);
    const std::string name = std::filesystem::path(mPath).stem().string();
    check(lib3mf_object_setnameutf8(object, name.c_str()), object, "name the object");
}

void Lib3mfPackage::check(LIB3MFRESULT result, PLib3MFBase* owner, const std::string& what) const
{
    if (result == LIB3MF_OK) return;
    DWORD code = 0;
    LPCSTR message = nullptr;
    if (owner) lib3mf_getlasterror(owner, &code, &message);
    throw std::runtime_error("cannot write '" + mPath + "': lib3mf failed to " + what +
                             (message ? std::string(": ") + message : std::string()));
}

void Lib3mfPackage::write(const std::array<std::string, 3>& uuids) const
{
    PLib3MFModel* model = mModel.get();
    PLib3MFModelBuildItem* itemRaw = nullptr;
    check(lib3mf_model_addbuilditem(model, mObject.get(), nullptr, &itemRaw), model, "add a build item");
    const Lib3mfHandle item(itemRaw);
    check(lib3mf_object_setuuidutf8(mObject.get(), uuids[0].c_str()), mObject.get(), "set a UUID");
    check(lib3mf_model_setbuilduuidutf8(model, uuids[1].c_str()), model, "set a UUID");
    check(lib3mf_builditem_setuuidutf8(itemRaw, uuids[2].c_str()), itemRaw, "set a UUID");
    PLib3MFModelWriter* writerRaw = nullptr;
    check(lib3mf_model_querywriter(model, "3mf", &writerRaw), model, "start the writer");
    const Lib3mfHandle writer(writerRaw);
    // Packing a large model takes seconds: a cancel meanwhile stops it.
    std::exception_ptr interrupted;
    check(lib3mf_writer_setprogresscallback(writerRaw, interruptPacking, &interrupted), writerRaw,
          "set the progress callback");
    auto checkPacking = [&](LIB3MFRESULT result, const std::string& what) {
        if (interrupted) std::rethrow_exception(interrupted);
        check(result, writerRaw, what);
    };
    ULONG64 size = 0;
    checkPacking(lib3mf_writer_getstreamsize(writerRaw, &size), "measure the package");
    std::vector<char> bytes(size);
    checkPacking(lib3mf_writer_writetobuffer(writerRaw, reinterpret_cast<BYTE*>(bytes.data()), size), "pack the model");
    AtomicFile file(mPath);
    file.stream().write(bytes.data(), std::streamsize(bytes.size()));
    file.commit();
}

}  // namespace voxlat
