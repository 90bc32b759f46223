// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/viewer/snapshot_renderer.h"
#include "vtk_errors.h"

#include <vtkImageData.h>
#include <vtkNew.h>
#include <vtkPNGWriter.h>

#include <cerrno>
#include <cstdio>
#include <cstring>
#include <stdexcept>
#include <string>

namespace iwlomap::viewer {

std::array<std::uint8_t, 3> RgbImage::pixel(int x, int y) const {
  if (x < 0 || y < 0 || x >= width || y >= height)
    throw std::out_of_range("RgbImage::pixel: (" + std::to_string(x) + ", " + std::to_string(y) + ") is outside the " +
                            std::to_string(width) + " x " + std::to_string(height) + " image");
  const std::size_t i = (static_cast<std::size_t>(y) * static_cast<std::size_t>(width) + static_cast<std::size_t>(x)) * 3;
  return {rgb[i], rgb[i + 1], rgb[i + 2]};
}

void write_png(const RgbImage& image, const std::string& path) {
  if (image.width <= 0 || image.height <= 0 ||
      image.rgb.size() != static_cast<std::size_t>(image.width) * static_cast<std::size_t>(image.height) * 3)
    throw std::invalid_argument("write_png: a " + std::to_string(image.width) + " x " + std::to_string(image.height) +
                                " image needs " +
                                std::to_string(static_cast<long long>(image.width) * image.height * 3) +
                                " bytes, the buffer has " + std::to_string(image.rgb.size()));
  // Written beside the target and renamed over it, so a failed write never leaves a torn picture
  // (or truncates an older one). VTK's writer reports an unwritable path as "ran out of disk
  // space"; say what is wrong first.
  const std::string partial = path + ".partial";
  if (std::FILE* f = std::fopen(partial.c_str(), "wb")) {
    std::fclose(f);
  } else {
    throw std::runtime_error("write_png: cannot write '" + path + "': " + std::strerror(errno));
  }
  vtkNew<vtkImageData> data;
  data->SetDimensions(image.width, image.height, 1);
  data->AllocateScalars(VTK_UNSIGNED_CHAR, 3);
  // VTK images start at the bottom row; RgbImage starts at the top.
  auto* dst = static_cast<std::uint8_t*>(data->GetScalarPointer());
  const std::size_t row = static_cast<std::size_t>(image.width) * 3;
  for (int y = 0; y < image.height; ++y)
    std::memcpy(dst + static_cast<std::size_t>(image.height - 1 - y) * row,
                image.rgb.data() + static_cast<std::size_t>(y) * row, row);

  vtkNew<detail::VtkErrorCollector> errors;
  vtkNew<vtkPNGWriter> writer;
  errors->watch(writer);
  writer->SetFileName(partial.c_str());
  writer->SetInputData(data);
  writer->Write();
  if (writer->GetErrorCode() != 0 || errors->failed()) {
    std::remove(partial.c_str());
    throw std::runtime_error("write_png: cannot write '" + path + "'" +
                             (errors->failed() ? ": " + errors->messages() : std::string()));
  }
  if (std::rename(partial.c_str(), path.c_str()) != 0) {
    const std::string reason = std::strerror(errno);
    std::remove(partial.c_str());
    throw std::runtime_error("write_png: cannot write '" + path + "': " + reason);
  }
}

}  // namespace iwlomap::viewer
