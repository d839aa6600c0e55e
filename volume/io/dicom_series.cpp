// DICOM series folders through ITK's GDCMImageIO: see dicom_series.h. A DICOM file with cut
// pixel data only triggers a GDCM warning on the console, hence the capture of the chatter.

#include "volume/io/dicom_series.h"

#include "volume/error.h"
#include "volume/io/file_source.h"
#include "volume/io/geometry_check.h"
#include "volume/io/io_util.h"
#include "volume/io/itk_console.h"
#include "volume/io/pixel_convert.h"
#include "volume/io/probe.h"

#include <itkGDCMImageIO.h>

#include <tbb/parallel_for.h>

#include <algorithm>
#include <cmath>
#include <filesystem>
#include <fstream>
#include <map>
#include <sstream>
#include <thread>
#include <vector>

namespace fs = std::filesystem;

namespace flyover::imageio {

namespace {

/// What one DICOM file's header says (read by ITK's GDCMImageIO).
struct DicomFile {
    std::string path;
    bool readable = false;     ///< the header was read (series, position, ... are known)
    bool incomplete = false;   ///< readable, but its pixel data is cut short
    std::string problem;       ///< why it could not be read
    std::string seriesUid;
    std::string instance;      ///< Instance Number, for messages
    std::string tiltTag;       ///< Gantry/Detector Tilt (0018,1120), degrees, as written
    bool hasPosition = false, hasOrientation = false, hasPixelSpacing = false;
    Vec3d positionMm;          ///< Image Position (Patient), LPS
    Vec3d rowDir, colDir;      ///< directions of increasing column (i) and row (j) index
    double spacingI = 0, spacingJ = 0;
    int64_t nx = 0, ny = 0, frames = 1;
    unsigned components = 1;
};

bool hasDicmPreamble(const std::string& path)
{
    std::ifstream in(path, std::ios::binary);
    char b[132];
    return in.read(b, 132) && std::memcmp(b + 128, "DICM", 4) == 0;
}

DicomFile scanDicomFile(const std::string& path)
{
    DicomFile f;
    f.path = path;
    auto io = itk::GDCMImageIO::New();
    try {
        io->SetFileName(path);
        io->ReadImageInformation();
    } catch (const itk::ExceptionObject& e) {
        f.problem = itkReason(e);
        return f;
    } catch (const std::exception& e) {  // e.g. bad_alloc from a length field gone wild
        f.problem = e.what();
        return f;
    }
    f.readable = true;
    auto tag = [&](const char* t) {
        std::string v;
        return io->GetValueFromTag(t, v) ? trim(v) : std::string();
    };
    f.seriesUid = tag("0020|000e");
    f.instance = tag("0020|0013");
    f.tiltTag = tag("0018|1120");
    f.hasPosition = !tag("0020|0032").empty();
    f.hasOrientation = !tag("0020|0037").empty();
    f.hasPixelSpacing = !tag("0028|0030").empty();
    const unsigned dims = io->GetNumberOfDimensions();
    for (int c = 0; c < 3; ++c) f.positionMm[c] = c < int(dims) ? io->GetOrigin(c) : 0.0;
    const auto d0 = io->GetDirection(0), d1 = io->GetDirection(1);
    for (int r = 0; r < 3; ++r) {
        f.rowDir[r] = r < int(d0.size()) ? d0[r] : 0.0;
        f.colDir[r] = r < int(d1.size()) ? d1[r] : 0.0;
    }
    f.spacingI = io->GetSpacing(0);
    f.spacingJ = io->GetSpacing(1);
    f.nx = static_cast<int64_t>(io->GetDimensions(0));
    f.ny = static_cast<int64_t>(io->GetDimensions(1));
    f.frames = dims >= 3 ? static_cast<int64_t>(io->GetDimensions(2)) : 1;
    f.components = io->GetNumberOfComponents();
    return f;
}

/// GDCM reports cut pixel data only as a console warning.
bool saysIncompletePixelData(const std::string& chatter)
{
    return chatter.find("Incomplete Pixel Data") != std::string::npos;
}

/// Runs `work(i)` for i in [0, n) in parallel; when GDCM complained about truncated pixel
/// data, runs again one by one to name the files. Returns their indices (usually none).
template <typename Work>
std::vector<std::size_t> parallelFindIncomplete(std::size_t n, Work&& work)
{
    std::string chatter;
    {
        CapturedOutput capture;
        tbb::parallel_for(std::size_t(0), n, [&](std::size_t i) { work(i); });
        chatter = capture.take();
    }
    std::vector<std::size_t> found;
    if (!saysIncompletePixelData(chatter)) return found;
    for (std::size_t i = 0; i < n; ++i) {
        CapturedOutput capture;
        work(i);
        if (saysIncompletePixelData(capture.take())) found.push_back(i);
    }
    return found;
}

// A DicomFile as one tab-separated line, to come back from a probing child.
std::string oneField(std::string s)
{
    std::replace_if(s.begin(), s.end(), [](char c) { return c == '\t' || c == '\n' || c == '\r'; }, ' ');
    return s;
}

std::string serializeDicomFile(std::size_t index, const DicomFile& f)
{
    std::ostringstream os;
    os.precision(17);
    os << "R\t" << index << '\t' << f.readable << '\t' << f.incomplete << '\t' << oneField(f.problem) << '\t'
       << oneField(f.seriesUid) << '\t' << oneField(f.instance) << '\t' << oneField(f.tiltTag) << '\t'
       << f.hasPosition << '\t' << f.hasOrientation << '\t' << f.hasPixelSpacing;
    for (const Vec3d* v : {&f.positionMm, &f.rowDir, &f.colDir}) os << '\t' << v->x << '\t' << v->y << '\t' << v->z;
    os << '\t' << f.spacingI << '\t' << f.spacingJ << '\t' << f.nx << '\t' << f.ny << '\t' << f.frames << '\t'
       << f.components << '\n';
    return os.str();
}

/// Parses one "R" line into files[index]; false when malformed.
bool parseDicomFile(const std::string& line, std::vector<DicomFile>& files)
{
    std::vector<std::string> v;
    std::size_t start = 0;
    for (;;) {
        const auto tab = line.find('\t', start);
        v.push_back(line.substr(start, tab == std::string::npos ? std::string::npos : tab - start));
        if (tab == std::string::npos) break;
        start = tab + 1;
    }
    if (v.size() != 26 || v[0] != "R") return false;
    const std::size_t index = std::stoul(v[1]);
    if (index >= files.size()) return false;
    DicomFile& f = files[index];
    auto num = [&](int i) { return std::strtod(v[std::size_t(i)].c_str(), nullptr); };
    f.readable = v[2] == "1";
    f.incomplete = v[3] == "1";
    f.problem = v[4];
    f.seriesUid = v[5];
    f.instance = v[6];
    f.tiltTag = v[7];
    f.hasPosition = v[8] == "1";
    f.hasOrientation = v[9] == "1";
    f.hasPixelSpacing = v[10] == "1";
    f.positionMm = {num(11), num(12), num(13)};
    f.rowDir = {num(14), num(15), num(16)};
    f.colDir = {num(17), num(18), num(19)};
    f.spacingI = num(20);
    f.spacingJ = num(21);
    f.nx = std::atoll(v[22].c_str());
    f.ny = std::atoll(v[23].c_str());
    f.frames = std::atoll(v[24].c_str());
    f.components = static_cast<unsigned>(std::atol(v[25].c_str()));
    return true;
}

/// Reads every file's header, in forked children (one per core, each on a contiguous share
/// of the files): a file that makes GDCM abort is marked unreadable, and the scan goes on
/// after it in a new child.
std::vector<DicomFile> scanDicomFiles(const std::vector<std::string>& paths)
{
    std::vector<DicomFile> files(paths.size());
    for (std::size_t i = 0; i < paths.size(); ++i) files[i].path = paths[i];
    const std::size_t workers = std::max<std::size_t>(
        1, std::min<std::size_t>({paths.size(), std::max(1u, std::thread::hardware_concurrency()), 8}));
    std::vector<std::string> failures(workers);
    std::vector<std::thread> threads;
    for (std::size_t w = 0; w < workers; ++w) {
        const std::size_t begin = paths.size() * w / workers, end = paths.size() * (w + 1) / workers;
        threads.emplace_back([&, w, begin, end] {
            std::size_t next = begin;
            while (next < end) {
                uint64_t largest = 0;
                for (std::size_t i = next; i < end; ++i) largest = std::max(largest, fileBytes(paths[i]));
                const ChildOutcome child = runInChild(2 * largest + (uint64_t(512) << 20), [&](int fd) {
                    for (std::size_t i = next; i < end; ++i) {
                        writeAll(fd, "S\t" + std::to_string(i) + "\n");
                        CapturedOutput capture;
                        DicomFile f = scanDicomFile(paths[i]);
                        f.incomplete = f.readable && saysIncompletePixelData(capture.take());
                        writeAll(fd, serializeDicomFile(i, f));
                    }
                });
                std::size_t started = end, finished = next;
                bool lastDone = true;
                std::istringstream lines(child.output);
                std::string line;
                while (std::getline(lines, line)) {
                    if (line.rfind("S\t", 0) == 0) {
                        started = std::stoul(line.substr(2));
                        lastDone = false;
                    } else if (parseDicomFile(line, files)) {
                        finished = started + 1;
                        lastDone = true;
                    }
                }
                if (child.killed && !lastDone && started < end) {
                    files[started].readable = false;
                    files[started].problem = "malformed file: the DICOM reader (GDCM) aborted on it (" +
                                             signalText(child.signal) + ")";
                    next = started + 1;
                } else if (child.killed || child.exitCode != 0 || finished < end) {
                    failures[w] = "DICOM header scan stopped at " + paths[std::min(finished, end - 1)] + " (child " +
                                  (child.killed ? signalText(child.signal) : "exit code " + std::to_string(child.exitCode)) + ")";
                    return;
                } else {
                    next = end;
                }
            }
        });
    }
    for (auto& t : threads) t.join();
    for (const auto& f : failures)
        if (!f.empty()) throw std::runtime_error(f);
    return files;
}

std::string uidText(const std::string& uid) { return uid.empty() ? "(no Series Instance UID)" : uid; }

class DicomSeriesSource final : public ImageSource {
public:
    DicomSeriesSource(const std::string& dir, std::vector<DicomFile> slices, const ImageGeometry& g, bool regular,
                      std::vector<Vec3d> origins, std::vector<std::string> warnings, const std::string& uid)
        : mFiles(std::move(slices))
    {
        mName = dir;
        mGeometry = g;
        mRegular = regular;
        mSliceOriginsMm = std::move(origins);
        mWarnings = std::move(warnings);
        mDescription = "DICOM series " + uidText(uid) + " (" + std::to_string(mFiles.size()) +
                       " files) via ITK GDCMImageIO (GDCM), read file by file";
    }

    void readSlices(int64_t k0, int64_t k1, float* out) override
    {
        const auto& s = mGeometry.size;
        if (!(0 <= k0 && k0 < k1 && k1 <= s[2])) throw std::out_of_range("readSlices: slice range");
        const std::size_t count = static_cast<std::size_t>(k1 - k0);
        const std::size_t perSlice = static_cast<std::size_t>(s[0] * s[1]);
        std::vector<std::string> errors(count);
        std::vector<std::size_t> badVoxel(count, perSlice);
        // Decoding (JPEG 2000 above all) dominates: one file per task.
        const auto incomplete = parallelFindIncomplete(count, [&](std::size_t n) {
            errors[n] = readOne(mFiles[static_cast<std::size_t>(k0) + n].path, out + n * perSlice, badVoxel[n]);
        });
        if (!incomplete.empty())
            throw InputError(mFiles[static_cast<std::size_t>(k0) + incomplete.front()].path +
                             ": pixel data is incomplete (the file is truncated)");
        for (std::size_t n = 0; n < count; ++n) {
            if (!errors[n].empty()) throw InputError(errors[n]);
            if (badVoxel[n] < perSlice)
                throwNonFinite(mFiles[static_cast<std::size_t>(k0) + n].path, s, k0 + int64_t(n), badVoxel[n],
                               out[n * perSlice + badVoxel[n]]);
        }
    }

private:
    /// Reads one slice file (GDCMImageIO applies Rescale Slope/Intercept); returns an error
    /// message or "" and sets `bad` to the first non-finite voxel.
    std::string readOne(const std::string& path, float* out, std::size_t& bad) const
    {
        const auto& s = mGeometry.size;
        auto io = itk::GDCMImageIO::New();
        try {
            io->SetFileName(path);
            io->ReadImageInformation();
            if (static_cast<int64_t>(io->GetDimensions(0)) != s[0] || static_cast<int64_t>(io->GetDimensions(1)) != s[1])
                return path + ": slice size changed since the series was scanned";
            const std::size_t n = static_cast<std::size_t>(s[0] * s[1]);
            const std::size_t bytes = componentBytes(io->GetComponentType());
            if (bytes == 0 || io->GetNumberOfComponents() != 1)
                return path + ": unsupported pixel type " +
                       itk::ImageIOBase::GetComponentTypeAsString(io->GetComponentType());
            std::vector<char> native(n * bytes);
            itk::ImageIORegion region(io->GetNumberOfDimensions());
            for (unsigned d = 0; d < io->GetNumberOfDimensions(); ++d) {
                region.SetIndex(d, 0);
                region.SetSize(d, io->GetDimensions(d));
            }
            io->SetIORegion(region);
            io->Read(native.data());
            bad = toFloat(native.data(), io->GetComponentType(), n, out);
        } catch (const itk::ExceptionObject& e) {
            return path + ": cannot decode the pixel data: " + itkReason(e);
        }
        return "";
    }

    std::vector<DicomFile> mFiles;  // in slice order
};

/// The regular files under `dir` (recursively, sorted; no hidden files or folders, no DICOMDIR).
/// @throw InputError when the folder cannot be listed or holds no file
std::vector<std::string> listFolder(const std::string& dir)
{
    std::vector<std::string> paths;
    std::error_code ec;
    for (auto it = fs::recursive_directory_iterator(dir, fs::directory_options::skip_permission_denied, ec);
         !ec && it != fs::recursive_directory_iterator(); it.increment(ec)) {
        const std::string name = it->path().filename().string();
        if (!name.empty() && name[0] == '.') {
            if (it->is_directory()) it.disable_recursion_pending();
            continue;
        }
        if (it->is_regular_file() && lowerCase(name) != "dicomdir") paths.push_back(it->path().string());
    }
    if (ec) throw InputError(dir + ": cannot list the folder: " + ec.message());
    std::sort(paths.begin(), paths.end());
    if (paths.empty()) throw InputError(dir + ": the folder is empty (expected a DICOM series)");
    return paths;
}

/// Series by UID (the indices of their files); files that are not DICOM images are ignored,
/// DICOM ones that fail go to `broken`, to be reported when they matter.
/// @throw InputError when there is no series
std::map<std::string, std::vector<std::size_t>> groupSeries(const std::string& dir, const std::vector<DicomFile>& files,
                                                            std::vector<std::size_t>& broken)
{
    std::map<std::string, std::vector<std::size_t>> series;
    for (std::size_t i = 0; i < files.size(); ++i) {
        if (files[i].readable) series[files[i].seriesUid].push_back(i);
        else if (hasDicmPreamble(files[i].path)) broken.push_back(i);
    }
    if (series.empty()) {
        if (!broken.empty())
            throw InputError(files[broken.front()].path + ": unreadable DICOM file: " + files[broken.front()].problem);
        throw InputError(dir + ": no DICOM image found in the folder");
    }
    return series;
}

/// The note on the DICOM files that could not be read ("" when none), for the messages.
std::string brokenNote(const std::vector<DicomFile>& files, const std::vector<std::size_t>& broken)
{
    if (broken.empty()) return "";
    const DicomFile& b = files[broken.front()];
    return "; " + std::to_string(broken.size()) + " DICOM file(s) could not be read, e.g. " + b.path + ": " +
           b.problem;
}

/// The UID of the series to read: options.dicomSeriesUid, or else the one with the most files
/// (with a warning when there are several).
/// @throw InputError when options.dicomSeriesUid is not in the folder
std::string chooseSeries(const std::string& dir, const std::map<std::string, std::vector<std::size_t>>& series,
                         const ImageReadOptions& options, std::vector<std::string>& warnings)
{
    std::string chosen;
    std::string list;
    for (const auto& [uid, idx] : series)
        list += (list.empty() ? "" : ", ") + uidText(uid) + " (" + std::to_string(idx.size()) + " files)";
    if (!options.dicomSeriesUid.empty()) {
        if (!series.count(options.dicomSeriesUid))
            throw InputError(dir + ": no DICOM series " + options.dicomSeriesUid + " in the folder (it holds: " +
                             list + ")");
        chosen = options.dicomSeriesUid;
    } else {
        std::size_t best = 0;
        for (const auto& [uid, idx] : series)
            if (idx.size() > best) { best = idx.size(); chosen = uid; }
        if (series.size() > 1)
            warnings.push_back(dir + " holds " + std::to_string(series.size()) + " series: " + list + "; reading " +
                               uidText(chosen) + ", the one with the most files (choose with --series UID)");
    }
    return chosen;
}

/// Checks that the slices of series `chosen` are complete single-frame scalar images placed in
/// space, at least two, all of the first one's size, pixel spacing and orientation.
/// @throw InputError otherwise (`note`: brokenNote)
void checkSlices(const std::string& dir, const std::string& chosen, const std::vector<DicomFile>& sl,
                 const std::string& note)
{
    for (const auto& f : sl) {
        if (f.incomplete) throw InputError(f.path + ": pixel data is incomplete (the file is truncated)");
        if (f.frames > 1)
            throw InputError(f.path + ": a multi-frame file (" + std::to_string(f.frames) + " frames) inside a "
                             "series of single-frame files is not supported");
        if (f.components != 1)
            throw InputError(f.path + ": pixel type has " + std::to_string(f.components) +
                             " components (colour?); a scalar (grey-value) CT is needed");
        if (!f.hasPosition || !f.hasOrientation)
            throw InputError(f.path + ": no Image Position/Orientation (Patient) (0020,0032)/(0020,0037): "
                                      "its place in the volume is unknown (a secondary capture?)");
        if (!f.hasPixelSpacing)
            throw InputError(f.path + ": no Pixel Spacing (0028,0030): the in-plane voxel size is unknown");
    }
    if (sl.size() < 2)
        throw InputError(dir + ": DICOM series " + uidText(chosen) + " has a single slice (" + fileName(sl[0].path) +
                         "); image is 2D, a 3D volume is needed" + note);

    const DicomFile& ref = sl.front();
    for (const auto& f : sl) {
        const bool same = f.nx == ref.nx && f.ny == ref.ny && length(f.rowDir - ref.rowDir) < 1e-4 &&
                          length(f.colDir - ref.colDir) < 1e-4 &&
                          std::fabs(f.spacingI - ref.spacingI) <= 1e-4 * ref.spacingI &&
                          std::fabs(f.spacingJ - ref.spacingJ) <= 1e-4 * ref.spacingJ;
        if (!same)
            throw InputError(dir + ": series " + uidText(chosen) + " mixes slice sizes, pixel spacings or "
                             "orientations (" + fileName(ref.path) + " vs " + fileName(f.path) + ")");
    }
}

/// A slice's file name and Instance Number, for messages.
std::string sliceName(const DicomFile& f)
{
    return fileName(f.path) + (f.instance.empty() ? "" : " (#" + f.instance + ")");
}

/// The steps between consecutive slices `sl` (in order along the normal, at positions `t` on it).
/// @throw InputError when two slices are at the same position
std::vector<double> sliceSteps(const std::string& dir, const std::vector<DicomFile>& sl, const std::vector<double>& t)
{
    std::vector<double> steps;
    for (std::size_t k = 0; k + 1 < sl.size(); ++k) {
        const double d = t[k + 1] - t[k];
        if (!(d > 1e-3)) {
            std::ostringstream os;
            os << dir << ": two slices at the same position along the slice normal: " << sliceName(sl[k]) << " and "
               << sliceName(sl[k + 1]) << " (several acquisitions or time points in one series?)";
            throw InputError(os.str());
        }
        steps.push_back(d);
    }
    return steps;
}

/// The median slice step and how many steps differ from it.
struct StepCheck {
    double median = 0;
    int uneven = 0;
};

/// Compares every step with the median: uneven steps (slices missing, uneven spacing) are
/// refused, or with options.allowGaps a warning.
/// @throw InputError on an uneven step without options.allowGaps (`note`: brokenNote)
StepCheck checkSteps(const std::string& dir, const std::vector<DicomFile>& sl, const std::vector<double>& steps,
                     const ImageReadOptions& options, const std::string& note, std::vector<std::string>& warnings)
{
    std::vector<double> sorted = steps;
    std::nth_element(sorted.begin(), sorted.begin() + long(sorted.size() / 2), sorted.end());
    const double median = sorted[sorted.size() / 2];
    // Slice positions are written as decimal strings with a few digits: allow 2% of a step.
    const double tolerance = std::max(0.02, 0.02 * median);
    int uneven = 0;
    std::ostringstream firstUneven;
    for (std::size_t k = 0; k + 1 < sl.size(); ++k) {
        const double d = steps[k];
        if (std::fabs(d - median) <= tolerance) continue;
        if (uneven++ > 0) continue;
        const double ratio = d / median;
        const long whole = std::lround(ratio);
        firstUneven.precision(4);
        if (whole >= 2 && std::fabs(d - double(whole) * median) <= tolerance)
            firstUneven << (whole - 1) << " slice(s) missing between " << sliceName(sl[k]) << " and "
                        << sliceName(sl[k + 1]) << " (" << d << " mm apart; the series steps " << median << " mm)";
        else
            firstUneven << "uneven slice spacing: " << d << " mm between " << sliceName(sl[k]) << " and "
                        << sliceName(sl[k + 1]) << ", " << median << " mm elsewhere";
    }
    std::string unevenText = firstUneven.str();
    if (uneven > 1) unevenText += " (and " + std::to_string(uneven - 1) + " more uneven step(s))";
    if (uneven > 0 && !options.allowGaps)
        throw InputError(dir + ": " + unevenText + "; refusing to guess the geometry (--allow-gaps interpolates "
                         "across gaps at the true slice positions)" + note);
    if (uneven > 0)
        warnings.push_back(dir + ": " + unevenText + "; accepted (--allow-gaps): voxels between these slices are "
                           "interpolated linearly at the true slice positions");
    return {median, uneven};
}

/// Gantry tilt: whether the slice positions drift sideways of the slice normal `n` (with a
/// warning); `t`: their positions along it.
bool checkTilt(const std::string& dir, const std::vector<DicomFile>& sl, const std::vector<double>& t, const Vec3d& n,
               std::vector<std::string>& warnings)
{
    const DicomFile& ref = sl.front();
    const std::size_t count = sl.size();
    double lateralMax = 0;
    for (std::size_t k = 0; k < count; ++k) {
        const Vec3d e = (sl[k].positionMm - sl[0].positionMm) - t[k] * n;
        lateralMax = std::max(lateralMax, length(e));
    }
    const double lateralTolerance = std::max(0.01, 0.05 * std::min(ref.spacingI, ref.spacingJ));
    const bool tilted = lateralMax > lateralTolerance;
    if (tilted) {
        const Vec3d e = (sl[count - 1].positionMm - sl[0].positionMm) - t[count - 1] * n;
        const double deg = std::atan2(length(e), t[count - 1]) * 180.0 / 3.14159265358979323846;
        std::ostringstream os;
        os.precision(3);
        os << dir << ": gantry tilt of " << deg << " degrees (slice positions drift " << length(e)
           << " mm sideways over " << t[count - 1] << " mm"
           << (ref.tiltTag.empty() ? std::string() : "; Gantry/Detector Tilt = " + ref.tiltTag)
           << "): corrected by sampling every slice at its true position on a grid aligned with the slice planes";
        warnings.push_back(os.str());
    }
    return tilted;
}

} // namespace

std::unique_ptr<ImageSource> openDicomFolder(const std::string& dir, const ImageReadOptions& options)
{
    const std::vector<std::string> paths = listFolder(dir);
    std::vector<DicomFile> files = scanDicomFiles(paths);

    std::vector<std::size_t> broken;
    std::map<std::string, std::vector<std::size_t>> series = groupSeries(dir, files, broken);
    std::vector<std::string> warnings;
    const std::string chosen = chooseSeries(dir, series, options, warnings);
    std::vector<DicomFile> sl;
    for (std::size_t i : series[chosen]) sl.push_back(files[i]);

    // One multi-frame file is a volume of its own.
    if (sl.size() == 1 && sl.front().frames > 1) return openFile(sl.front().path, options);
    const std::string note = brokenNote(files, broken);
    checkSlices(dir, chosen, sl, note);

    const Vec3d u = normalize(sl.front().rowDir), v = normalize(sl.front().colDir);
    const Vec3d n = normalize(cross(u, v));
    // Order by position along the slice normal: never by file name or Instance Number.
    std::sort(sl.begin(), sl.end(),
              [&](const DicomFile& a, const DicomFile& b) { return dot(a.positionMm, n) < dot(b.positionMm, n); });
    const DicomFile& ref = sl.front();
    const std::size_t count = sl.size();
    std::vector<double> t(count);
    for (std::size_t k = 0; k < count; ++k) t[k] = dot(sl[k].positionMm - sl[0].positionMm, n);
    const std::vector<double> steps = sliceSteps(dir, sl, t);
    const StepCheck stepCheck = checkSteps(dir, sl, steps, options, note, warnings);
    const bool tilted = checkTilt(dir, sl, t, n, warnings);

    ImageGeometry g;
    g.size = {ref.nx, ref.ny, static_cast<int64_t>(count)};
    const bool regular = stepCheck.uneven == 0 && !tilted;
    // The mean step, rounded to 1 nm: positions are decimal strings, and the rounding keeps
    // a 1.5 mm series at exactly 1.5 (as NIfTI or NRRD would hold it), not 1.4999999999.
    const double meanStep = std::round(t[count - 1] / double(count - 1) * 1e6) / 1e6;
    g.spacingMm = {ref.spacingI, ref.spacingJ, regular ? meanStep : stepCheck.median};
    g.originMm = sl[0].positionMm;
    for (int r = 0; r < 3; ++r) {
        g.direction[r][0] = u[r];
        g.direction[r][1] = v[r];
        g.direction[r][2] = n[r];
    }
    validateGeometry(g, dir);
    std::vector<Vec3d> origins;
    for (const auto& f : sl) origins.push_back(f.positionMm);
    return std::make_unique<DicomSeriesSource>(dir, std::move(sl), g, regular, std::move(origins), std::move(warnings),
                                               chosen);
}

} // namespace flyover::imageio
