// libFuzzer target: arbitrary bytes as a NIfTI, NRRD, MetaImage or DICOM file (the first
// byte picks the extension, or a DICOM folder), opened by openImage() and, when the header
// describes a small image, read in full. The contract under test: bad input gives an
// InputError, never a crash, a sanitizer report, a hang or another exception type.

#include "volume/error.h"
#include "volume/image_io.h"

#include <unistd.h>

#include <cstdint>
#include <cstdio>
#include <filesystem>
#include <string>
#include <vector>

namespace fs = std::filesystem;

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, std::size_t size)
{
    if (size < 1) return 0;
    static const char* const NAMES[] = {"scan.nii", "scan.nii.gz", "scan.nrrd", "scan.nhdr",
                                        "scan.mha", "scan.mhd",    "scan.dcm",  "series/IM0"};
    const unsigned mode = data[0] % 8;
    static const fs::path dir = fs::temp_directory_path() / ("flyover-fuzz-" + std::to_string(::getpid()));
    fs::remove_all(dir);
    fs::create_directories(dir / "series");
    const fs::path file = dir / NAMES[mode];
    if (std::FILE* f = std::fopen(file.c_str(), "wb")) {
        std::fwrite(data + 1, 1, size - 1, f);
        std::fclose(f);
    }
    const std::string path = mode == 7 ? (dir / "series").string() : file.string();
    try {
        auto source = flyover::openImage(path);
        const auto& g = source->geometry();
        if (g.voxelCount() <= (int64_t(1) << 20)) {  // read small images in full, two slabs
            std::vector<float> buf(static_cast<std::size_t>(g.voxelCount()));
            const int64_t half = g.size[2] / 2;
            if (half > 0) source->readSlices(0, half, buf.data());
            source->readSlices(half, g.size[2], buf.data() + static_cast<std::size_t>(g.size[0] * g.size[1] * half));
        }
    } catch (const flyover::InputError&) {
        // the expected outcome for bad input
    }
    return 0;
}
