// Single files through ITK's readers: see file_source.h.
//
// ITK's readers are trusted for parsing and geometry, not for telling us when data is
// missing: measured on ITK 5.2, a truncated .nii/.nii.gz reads "successfully" with the tail
// zero-filled and a short MetaImage only prints to std::cerr. Hence the explicit size checks
// (data_size.h), the decompression of gzipped NIfTI by flyover (gzip_stream.h, which reports
// truncation), the sentinel re-read for MetaImage, and the capture of the libraries' console
// chatter (itk_console.h).

#include "volume/io/file_source.h"

#include "volume/error.h"
#include "volume/io/data_size.h"
#include "volume/io/geometry_check.h"
#include "volume/io/gunzip.h"
#include "volume/io/io_util.h"
#include "volume/io/itk_console.h"
#include "volume/io/metaimage.h"
#include "volume/io/nifti1.h"
#include "volume/io/nifti2.h"
#include "volume/io/pixel_convert.h"
#include "volume/io/probe.h"

#include <itkImageIOBase.h>

#include <algorithm>
#include <cstring>
#include <filesystem>
#include <new>
#include <vector>

namespace fs = std::filesystem;

namespace flyover::imageio {

namespace {

/// A NIfTI, NRRD, MetaImage or single DICOM file through one ITK ImageIO.
class FileSource final : public ImageSource {
public:
    FileSource(const std::string& path, itk::ImageIOBase::Pointer io, const ImageGeometry& g, bool streamed,
               std::unique_ptr<TempDir> temp, const std::string& description)
        : mIo(std::move(io)), mTemp(std::move(temp)), mStreamed(streamed),
          mType(mIo->GetComponentType()), mComponentBytes(mIo->GetComponentSize())
    {
        mName = path;
        mGeometry = g;
        mRegular = true;
        for (int64_t k = 0; k < g.size[2]; ++k) mSliceOriginsMm.push_back(g.worldFromIndex({0, 0, double(k)}));
        mDescription = description;
        mSentinelCheck = formatOfIo(*mIo) == "MetaImage";
        if (!mStreamed) mHeldBytes = static_cast<int64_t>(sliceBytes() * static_cast<std::size_t>(g.size[2]));
    }

    void addWarning(const std::string& text) { mWarnings.push_back(text); }

    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const auto& s = mGeometry.size;
        if (!(0 <= k0 && k0 < k1 && k1 <= s[2])) throw std::out_of_range("readSlices: slice range");
        const std::size_t voxelsPerSlice = static_cast<std::size_t>(s[0] * s[1]);
        const std::size_t n = voxelsPerSlice * static_cast<std::size_t>(k1 - k0);
        const char* native = nullptr;
        if (mStreamed) {
            mSlab.resize(sliceBytes() * static_cast<std::size_t>(k1 - k0));
            readRegion(k0, k1, mSlab.data(), mSlab.size());
            native = mSlab.data();
        } else {
            if (mWhole.empty()) {
                try {
                    mWhole.resize(sliceBytes() * static_cast<std::size_t>(s[2]));
                } catch (const std::bad_alloc&) {
                    throw InputError(mName + ": cannot allocate " + bytesText(sliceBytes() * std::size_t(s[2])) +
                                     " for the " + sizeText(s) + " voxels its header describes");
                }
                readRegion(0, s[2], mWhole.data(), mWhole.size());
            }
            native = mWhole.data() + sliceBytes() * static_cast<std::size_t>(k0);
        }
        const std::size_t bad = toFloat(native, mType, n, out);
        if (bad < n) throwNonFinite(mName, s, k0, bad, out[bad]);
    }

private:
    std::size_t sliceBytes() const
    {
        return static_cast<std::size_t>(mGeometry.size[0] * mGeometry.size[1]) * mComponentBytes;
    }

    void readRegion(int64_t k0, int64_t k1, char* buffer, std::size_t bytes)
    {
        const unsigned dims = mIo->GetNumberOfDimensions();
        itk::ImageIORegion region(dims);
        for (unsigned d = 0; d < dims; ++d) {
            region.SetIndex(d, 0);
            region.SetSize(d, d < 2 ? static_cast<itk::SizeValueType>(mGeometry.size[d]) : 1);
        }
        region.SetIndex(2, k0);
        region.SetSize(2, static_cast<itk::SizeValueType>(k1 - k0));
        // MetaIO leaves the unread tail of a short file untouched and only prints a message:
        // fill with a pattern, and if the tail still holds it, read again with another pattern
        // (real data cannot match both).
        const unsigned char patterns[2] = {0xA5, 0x5A};
        const std::size_t tail = std::min<std::size_t>(bytes, 16);
        for (int attempt = 0; attempt < (mSentinelCheck ? 2 : 1); ++attempt) {
            if (mSentinelCheck) std::memset(buffer, patterns[attempt], bytes);
            std::string chatter;
            try {
                CapturedOutput capture;
                mIo->SetIORegion(region);
                mIo->Read(buffer);
                chatter = capture.take();
            } catch (const itk::ExceptionObject& e) {
                throw InputError(mName + ": cannot read the voxel data: " + itkReason(e));
            }
            if (chatter.find("not read completely") != std::string::npos)
                throw InputError(mName + ": the voxel data ends early (truncated file, or header/data size mismatch)");
            if (!mSentinelCheck) return;
            const bool untouched = std::all_of(buffer + bytes - tail, buffer + bytes, [&](char c) {
                return static_cast<unsigned char>(c) == patterns[attempt];
            });
            if (!untouched) return;
        }
        throw InputError(mName + ": the voxel data ends early (truncated file, or header/data size mismatch)");
    }

    itk::ImageIOBase::Pointer mIo;
    std::unique_ptr<TempDir> mTemp;  // the decompressed copy that mIo reads, if any
    bool mStreamed;
    bool mSentinelCheck = false;
    IOComponentEnum mType;
    std::size_t mComponentBytes;
    std::vector<char> mSlab;   // streamed: the native slab buffer
    std::vector<char> mWhole;  // buffered: the whole image in its native type
};

} // namespace

std::unique_ptr<ImageSource> openFile(const std::string& path, const ImageReadOptions& options)
{
    if (fileBytes(path) == 0) throw InputError(path + ": the file is empty");
    if (formatFromName(path) == "MetaImage") checkMetaImageHeaderText(path);
    const std::string probe = probeHeaderInChild(path);
    if (!probe.empty() && probe != "NOIO") throw InputError(path + ": " + probe);
    itk::ImageIOBase::Pointer io = probe == "NOIO" ? nullptr : createIo(path);
    if (!io) {
        const std::string format = formatFromName(path);
        if (format == "NIfTI" && isNifti2(path)) {
            return openNifti2(path, options.dicomSeriesUid.empty()
                                        ? std::string()
                                        : path + ": a DICOM series UID (" + options.dicomSeriesUid +
                                              ") only selects within a DICOM folder; ignored for a single file");
        }
        if (!format.empty())
            throw InputError(path + ": not a readable " + format + " file (its header is corrupt, truncated or "
                                    "of another format)");
        throw InputError(path + ": not a readable image (supported: NIfTI .nii/.nii.gz, NRRD .nrrd/.nhdr, "
                                "MetaImage .mha/.mhd, DICOM file or series folder)");
    }
    readInformation(*io, path, path);
    const std::string format = formatOfIo(*io);
    ImageGeometry g = checkHeader(*io, path);
    if (format == "NIfTI") {
        // ITK 5.2 turns metre and micron spacing into mm but leaves qoffset/srow offsets in
        // the file's unit (measured: tests/volume/nifti2_test.cpp): scale the origin too.
        const int units = std::atoi(metaString(*io, "xyzt_units").c_str()) & 0x07;
        const double unit = units == 1 ? 1000.0 : units == 3 ? 0.001 : 1.0;
        for (int c = 0; c < 3; ++c) g.originMm[c] *= unit;
    }
    const std::string typeName = itk::ImageIOBase::GetComponentTypeAsString(io->GetComponentType());
    const DataFile data = dataFileOf(*io, path);
    checkDataSize(data, path, g, typeName);

    std::unique_ptr<TempDir> temp;
    bool streamed = false;
    std::string how;
    if (format == "NIfTI") {
        // The voxels straight from the file (inflated while read when gzipped); ITK's reader
        // only for layouts flyover leaves to it.
        const std::string flyoverHow =
            data.compressed ? "voxels inflated by ISA-L while streamed by slab" : "voxels streamed by slab";
        const std::string warning = options.dicomSeriesUid.empty()
                                        ? std::string()
                                        : path + ": a DICOM series UID (" + options.dicomSeriesUid +
                                              ") only selects within a DICOM folder; ignored for a single file";
        auto own = openNifti1Voxels(path, g, data, metaString(*io, "bitpix"),
                                    "NIfTI (header via ITK NiftiImageIO, " + flyoverHow + " by flyover)", warning);
        if (own) return own;
        streamed = true;
        how = "streamed by slab";
        if (data.compressed) {
            // ITK would re-inflate the file from its start for every region: inflate it
            // once into a temporary uncompressed copy and stream from that.
            temp = std::make_unique<TempDir>();
            fs::path copy;
            if (data.path == fs::path(path)) {
                copy = temp->path() / "scan.nii";
            } else {  // an Analyze-style pair: NAME.hdr + NAME.img.gz
                if (!endsWith(lowerCase(path), ".hdr"))
                    throw InputError(path + ": open the .hdr file of a .hdr/.img.gz pair");
                fs::copy_file(path, temp->path() / "scan.hdr");
                copy = temp->path() / "scan.img";
            }
            gunzipFile(data.path, copy, data.offset + data.bytes, path);
            const fs::path readPath = data.path == fs::path(path) ? copy : temp->path() / "scan.hdr";
            io = createIo(readPath.string());
            if (!io) throw InputError(path + ": the decompressed NIfTI header is unreadable");
            readInformation(*io, readPath.string(), path);
            how = "gunzipped by ISA-L to a temporary file, then streamed by slab";
        }
    } else if (format == "MetaImage" && io->CanStreamRead()) {
        streamed = true;
        how = "streamed by slab";
    } else {
        how = "read whole in its native type (" + typeName + "; " + format + " cannot be read by region)";
    }
    const std::string description = format + " via ITK " + io->GetNameOfClass() + ", " + how;
    auto source = std::make_unique<FileSource>(path, io, g, streamed, std::move(temp), description);
    if (!options.dicomSeriesUid.empty())
        source->addWarning(path + ": a DICOM series UID (" + options.dicomSeriesUid +
                           ") only selects within a DICOM folder; ignored for a single file");
    return source;
}

} // namespace flyover::imageio
