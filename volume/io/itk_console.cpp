// ITK IO registration, console capture and exception text: see itk_console.h.

#include "volume/io/itk_console.h"

#include "volume/io/io_util.h"

#include <itkGDCMImageIOFactory.h>
#include <itkMetaImageIOFactory.h>
#include <itkNiftiImageIOFactory.h>
#include <itkNrrdImageIOFactory.h>

#include <iostream>
#include <sstream>

namespace flyover::imageio {

void registerImageIO()
{
    static std::once_flag once;
    std::call_once(once, [] {
        itk::NiftiImageIOFactory::RegisterOneFactory();
        itk::NrrdImageIOFactory::RegisterOneFactory();
        itk::MetaImageIOFactory::RegisterOneFactory();
        itk::GDCMImageIOFactory::RegisterOneFactory();
        // Our own checks report what matters; ITK's warnings would only add console lines.
        itk::Object::GlobalWarningDisplayOff();
    });
}

std::string itkReason(const itk::ExceptionObject& e)
{
    std::istringstream in(e.GetDescription());
    std::string line, first, lastNrrd;
    while (std::getline(in, line)) {
        line = trim(line);
        if (line.empty()) continue;
        if (line.rfind("[nrrd]", 0) == 0) lastNrrd = trim(line.substr(6));
        else if (first.empty()) first = line;
    }
    std::string r = !lastNrrd.empty() ? lastNrrd : first;
    if (r.rfind("ITK ERROR:", 0) == 0 || r.rfind("itk::ERROR:", 0) == 0) {
        const auto p = r.find("): ");
        if (p != std::string::npos) r = r.substr(p + 3);
    }
    if (r.empty()) r = "unknown ITK error";
    return r;
}

std::string formatOfIo(const itk::ImageIOBase& io)
{
    const std::string c = io.GetNameOfClass();
    if (c == "NiftiImageIO") return "NIfTI";
    if (c == "NrrdImageIO") return "NRRD";
    if (c == "MetaImageIO") return "MetaImage";
    if (c == "GDCMImageIO") return "DICOM";
    return c;
}

} // namespace flyover::imageio
