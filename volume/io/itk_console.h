/// @file itk_console.h
/// @brief ITK's side of the scan readers: registering the four IO factories, capturing the
///        libraries' console chatter (ITK, GDCM and MetaIO print warnings, and some data
///        errors only there), and one-line reasons from ITK exceptions. Internal to volume/.
#pragma once

#include <itkImageIOBase.h>

#include <iosfwd>
#include <mutex>
#include <streambuf>
#include <string>

namespace flyover::imageio {

/// Registers NIfTI, NRRD, MetaImage and GDCM (DICOM) readers, once; no other format exists.
/// IO factories are registered explicitly (instead of ITK_USE_FILE's generated manager), so
/// ITK's global definitions stay out of other code.
void registerImageIO();

/// A string sink safe to write from several threads (DICOM files are decoded in parallel).
class LockedStringBuf : public std::streambuf {
public:
    std::string take()
    {
        std::lock_guard<std::mutex> lock(mMutex);
        std::string t;
        t.swap(mText);
        return t;
    }

protected:
    int_type overflow(int_type c) override
    {
        if (!traits_type::eq_int_type(c, traits_type::eof())) {
            std::lock_guard<std::mutex> lock(mMutex);
            mText.push_back(traits_type::to_char_type(c));
        }
        return traits_type::not_eof(c);
    }
    std::streamsize xsputn(const char* s, std::streamsize n) override
    {
        std::lock_guard<std::mutex> lock(mMutex);
        mText.append(s, static_cast<std::size_t>(n));
        return n;
    }

private:
    std::mutex mMutex;
    std::string mText;
};

/// While alive, std::cout and std::cerr (where ITK, GDCM's trace and MetaIO write their
/// warnings) go to a buffer instead of the console.
class CapturedOutput {
public:
    CapturedOutput() : mOldErr(std::cerr.rdbuf(&mBuf)), mOldOut(std::cout.rdbuf(&mBuf)) {}
    ~CapturedOutput()
    {
        std::cerr.rdbuf(mOldErr);
        std::cout.rdbuf(mOldOut);
    }
    CapturedOutput(const CapturedOutput&) = delete;
    CapturedOutput& operator=(const CapturedOutput&) = delete;
    std::string take() { return mBuf.take(); }

private:
    LockedStringBuf mBuf;
    std::streambuf* mOldErr;
    std::streambuf* mOldOut;
};

/// One line out of an ITK exception: NRRD's error stack ends with its deepest cause; other
/// readers put theirs first. The "ITK ERROR: Class(0x...): " prefix is dropped.
std::string itkReason(const itk::ExceptionObject& e);

/// "NIfTI", "NRRD", "MetaImage" or "DICOM" for a reader.
std::string formatOfIo(const itk::ImageIOBase& io);

} // namespace flyover::imageio
