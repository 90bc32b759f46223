// SPDX-License-Identifier: BSD-3-Clause
#include "cloud_check.h"

#include <iwlomap/filters/pointcloud2.h>

#include "args.h"

#include <algorithm>
#include <cerrno>
#include <cstdlib>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <limits>
#include <optional>
#include <sstream>
#include <stdexcept>
#include <vector>

namespace iwlomap::tool {

namespace {

// A header longer than this is not a cloud header (PCL's own files have a few hundred bytes).
constexpr std::size_t kMaxHeaderBytes = 1 << 20;
// Values per point (the sum of COUNTs, or PLY properties) beyond which a file is refused.
constexpr std::uint64_t kMaxValuesPerPoint = 1 << 16;

// \p what quotes the file's own bytes: control and non-ASCII bytes are written as \xNN, so that
// the message stays one line a terminal shows as it is.
[[noreturn]] void fail(const std::string& path, const std::string& what) {
  std::string shown;
  for (const char c : what) {
    const auto u = static_cast<unsigned char>(c);
    if (u >= 0x20 && u < 0x7f) {
      shown += c;
    } else {
      static const char* hex = "0123456789abcdef";
      shown += "\\x";
      shown += hex[u >> 4];
      shown += hex[u & 15];
    }
  }
  throw std::runtime_error("'" + path + "': " + shown);
}

std::vector<std::string> words(const std::string& line) {
  std::istringstream in(line);
  std::vector<std::string> out;
  for (std::string w; in >> w;) out.push_back(w);
  return out;
}

// A non-negative integer with nothing else in the word (no sign, no exponent, no overflow).
std::optional<std::uint64_t> whole_number(const std::string& w) {
  if (w.empty() || w.size() > 19 || !std::all_of(w.begin(), w.end(), [](char c) { return c >= '0' && c <= '9'; }))
    return std::nullopt;
  return std::stoull(w);
}

std::optional<double> finite_number(const std::string& w) {
  char* end = nullptr;
  const double v = std::strtod(w.c_str(), &end);
  if (end == w.c_str() || *end != '\0' || !std::isfinite(v)) return std::nullopt;
  return v;
}

// The text of a comment line after its marker (which ends at \p marker_end) and the blanks after it.
std::string after_marker(const std::string& line, std::size_t marker_end) {
  const std::size_t start = line.find_first_not_of(" \t", marker_end);
  return start == std::string::npos ? std::string() : line.substr(start);
}

// Reads header lines (up to the line that starts with `last`) with the offset of the data after it.
struct HeaderLines {
  std::vector<std::string> lines;
  std::uint64_t data_offset = 0;
};

HeaderLines read_header(const std::string& path, std::ifstream& in, const std::string& last) {
  HeaderLines h;
  std::string line;
  while (std::getline(in, line)) {
    h.data_offset += line.size() + 1;
    if (h.data_offset > kMaxHeaderBytes) fail(path, "no end of header in the first 1 MiB (" + last + " line missing)");
    if (!line.empty() && line.back() == '\r') line.pop_back();
    h.lines.push_back(line);
    if (line.rfind(last, 0) == 0) return h;
  }
  fail(path, "the header ends before its " + last + " line (truncated or not a cloud file)");
}

// PCL's PCD header parser does not stop at the DATA line: it goes on past empty lines and comments
// while the next line starts with a header keyword (as a prefix of its first word), so the first
// bytes of a binary body can add header lines: other fields, a WIDTH that allocates gigabytes, a
// DATA line that throws (all found by fuzzing). Skipped empty and comment lines are harmless (the
// data still starts after the DATA line). Refuses a body whose first lines PCL would read so.
void check_body_start(const std::string& path, std::uint64_t data_offset) {
  static const char* const kKeywords[] = {"VERSION", "FIELDS", "COLUMNS", "SIZE", "TYPE",  "COUNT",
                                          "WIDTH",   "HEIGHT", "VIEWPOINT", "POINTS", "DATA"};
  std::ifstream in(path, std::ios::binary);
  in.seekg(static_cast<std::streamoff>(data_offset));
  std::string line;
  std::uint64_t scanned = 0;
  while (std::getline(in, line) && scanned <= kMaxHeaderBytes) {
    scanned += line.size() + 1;
    std::istringstream words_of(line);
    std::string first;
    words_of >> first;
    if (line.empty() || (!first.empty() && first[0] == '#')) continue;
    for (const char* k : kKeywords)
      if (first.rfind(k, 0) == 0)
        fail(path, std::string("the data after the DATA line starts with a line that PCL's reader would take as a ") +
                       k + " header line");
    return;
  }
}

std::uint64_t lines_after(std::ifstream& in, std::uint64_t limit) {
  std::uint64_t n = 0;
  std::vector<char> buf(1 << 16);
  while (n < limit && in) {
    in.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    n += static_cast<std::uint64_t>(std::count(buf.data(), buf.data() + in.gcount(), '\n'));
  }
  return n;
}

// One value of an ASCII row: its field, TYPE (F, I, U) and SIZE in bytes.
struct AsciiField {
  std::string name;
  char type;
  std::uint64_t size;
};

// True when \p w is one whole number of the field's type and range: F any decimal or
// scientific number (nan and inf too, as PCL writes them), I and U integers that fit the size.
bool ascii_value_fits(const std::string& w, const AsciiField& f) {
  if (w.empty()) return false;
  errno = 0;
  char* end = nullptr;
  if (f.type == 'F') {
    static_cast<void>(std::strtod(w.c_str(), &end));
    return end != w.c_str() && *end == '\0' && errno != ERANGE;
  }
  const unsigned bits = static_cast<unsigned>(f.size * 8);
  if (f.type == 'I') {
    const long long v = std::strtoll(w.c_str(), &end, 10);
    if (end == w.c_str() || *end != '\0' || errno == ERANGE) return false;
    if (bits >= 64) return true;
    const long long limit = 1LL << (bits - 1);
    return v >= -limit && v < limit;
  }
  if (w[0] == '-') return false;
  const unsigned long long v = std::strtoull(w.c_str(), &end, 10);
  if (end == w.c_str() || *end != '\0' || errno == ERANGE) return false;
  return bits >= 64 || v < (1ULL << bits);
}

// Every data line of an ASCII PCD holds exactly the header's values, each a whole number of its
// field's type; exactly \p points such lines (empty lines after them allowed). \p in stands at
// the data, which starts on line \p header_lines + 1. PCL's reader would take a short row, a word
// that is not a number or "1,5" as zeros or partial numbers without a word.
void check_ascii_rows(const std::string& path, std::ifstream& in, std::size_t header_lines, std::uint64_t points,
                      const std::vector<AsciiField>& columns) {
  std::string line;
  std::uint64_t rows = 0;
  std::size_t line_number = header_lines;
  std::vector<std::string> w;
  while (std::getline(in, line)) {
    ++line_number;
    if (!line.empty() && line.back() == '\r') line.pop_back();
    w = words(line);
    if (w.empty()) continue;
    const std::string where = "line " + std::to_string(line_number) + ": ";
    if (rows == points)
      fail(path, where + "a row after the " + std::to_string(points) + " points the header promises");
    if (w.size() != columns.size())
      fail(path, where + std::to_string(w.size()) + " values, but the header declares " +
                     std::to_string(columns.size()) + " per point");
    for (std::size_t i = 0; i < w.size(); ++i)
      if (!ascii_value_fits(w[i], columns[i]))
        fail(path, where + "field '" + columns[i].name + "' holds '" + w[i] + "', not " +
                       (columns[i].type == 'F' ? std::string("a number")
                                               : std::string(columns[i].type == 'I' ? "an integer" : "an unsigned integer") +
                                                     " of " + std::to_string(columns[i].size) + " byte(s)"));
    ++rows;
  }
  if (rows < points)
    fail(path, "the header promises " + std::to_string(points) + " points but the file has " + std::to_string(rows) +
                   " rows of data (truncated?)");
}

CloudHeader check_pcd(const std::string& path, std::uint64_t file_size) {
  std::ifstream in(path, std::ios::binary);
  const HeaderLines h = read_header(path, in, "DATA");
  std::vector<std::string> fields, types;
  std::vector<std::uint64_t> sizes, counts;
  std::optional<std::uint64_t> width, height, points;
  std::string data;
  CloudHeader out;
  std::vector<std::pair<std::string, std::size_t>> seen;  // header keyword, its line number
  for (std::size_t line_number = 1; line_number <= h.lines.size(); ++line_number) {
    const std::string& line = h.lines[line_number - 1];
    const auto w = words(line);
    if (!w.empty() && w[0][0] == '#') out.comments.push_back(after_marker(line, line.find('#') + 1));
    if (w.empty() || w[0][0] == '#') continue;
    const std::string& key = w[0];
    // A header line given twice is refused, not decided by which comes last.
    const std::string canonical = key == "COLUMNS" ? "FIELDS" : key;
    for (const auto& [k, n] : seen)
      if (k == canonical)
        fail(path, "line " + std::to_string(line_number) + ": a second " + key + " line (the first is line " +
                       std::to_string(n) + ")");
    seen.emplace_back(canonical, line_number);
    const std::vector<std::string> v(w.begin() + 1, w.end());
    const auto numbers = [&](std::vector<std::uint64_t>& dst) {
      for (const std::string& s : v) {
        const auto n = whole_number(s);
        if (!n) fail(path, key + " '" + s + "' is not a whole number >= 0");
        dst.push_back(*n);
      }
    };
    const auto single = [&](std::optional<std::uint64_t>& dst) {
      if (v.size() != 1 || !whole_number(v[0])) fail(path, key + " must be one whole number >= 0, got '" + line + "'");
      dst = whole_number(v[0]);
    };
    if (key == "VERSION") {
    } else if (key == "FIELDS" || key == "COLUMNS") {
      fields = v;
    } else if (key == "SIZE") {
      numbers(sizes);
    } else if (key == "TYPE") {
      types = v;
    } else if (key == "COUNT") {
      numbers(counts);
    } else if (key == "WIDTH") {
      single(width);
    } else if (key == "HEIGHT") {
      single(height);
    } else if (key == "POINTS") {
      single(points);
    } else if (key == "VIEWPOINT") {
      if (v.size() != 7) fail(path, "VIEWPOINT needs 7 numbers (x y z qw qx qy qz), got " + std::to_string(v.size()));
      for (const std::string& s : v)
        if (!finite_number(s)) fail(path, "VIEWPOINT value '" + s + "' is not a finite number");
      out.has_viewpoint = true;
    } else if (key == "DATA") {
      if (v.size() != 1) fail(path, "DATA must be ascii, binary or binary_compressed");
      data = v[0];
    } else {
      fail(path, "unknown header line '" + line + "'");
    }
  }
  if (fields.empty()) fail(path, "no FIELDS");
  for (std::size_t i = 0; i < fields.size(); ++i)
    for (std::size_t j = 0; j < i; ++j)
      if (fields[i] == fields[j] && fields[i] != "_") fail(path, "FIELDS lists '" + fields[i] + "' twice");
  if (fields.size() > kMaxValuesPerPoint) fail(path, "FIELDS lists " + std::to_string(fields.size()) + " fields");
  if (counts.empty()) counts.assign(fields.size(), 1);
  if (sizes.size() != fields.size() || types.size() != fields.size() || counts.size() != fields.size())
    fail(path, "FIELDS, SIZE, TYPE and COUNT list " + std::to_string(fields.size()) + ", " +
                   std::to_string(sizes.size()) + ", " + std::to_string(types.size()) + " and " +
                   std::to_string(counts.size()) + " entries; they must match");
  std::uint64_t point_size = 0, values = 0;
  for (std::size_t i = 0; i < fields.size(); ++i) {
    const std::uint64_t s = sizes[i];
    if (s != 1 && s != 2 && s != 4 && s != 8) fail(path, "SIZE of field '" + fields[i] + "' is " + std::to_string(s) + ", not 1, 2, 4 or 8");
    if (types[i] != "F" && types[i] != "I" && types[i] != "U")
      fail(path, "TYPE of field '" + fields[i] + "' is '" + types[i] + "', not F, I or U");
    if (types[i] == "F" && s != 4 && s != 8) fail(path, "field '" + fields[i] + "' is a float of " + std::to_string(s) + " bytes");
    if (counts[i] < 1 || counts[i] > kMaxValuesPerPoint)
      fail(path, "COUNT of field '" + fields[i] + "' is " + std::to_string(counts[i]) + ", not in [1, 65536]");
    values += counts[i];
    point_size += s * counts[i];
  }
  if (values > kMaxValuesPerPoint) fail(path, std::to_string(values) + " values per point (COUNT) is more than a cloud has");
  if (!width || !height) fail(path, "WIDTH and HEIGHT are required");
  if (*width > std::numeric_limits<std::uint32_t>::max() || *height > std::numeric_limits<std::uint32_t>::max())
    fail(path, "WIDTH or HEIGHT beyond 2^32 - 1");
  out.points = *width * *height;  // both < 2^32: no overflow
  out.fields = fields.size();
  out.point_size = point_size;
  if (points && *points != out.points)
    fail(path, "POINTS is " + std::to_string(*points) + " but WIDTH x HEIGHT is " + std::to_string(out.points));
  const std::uint64_t body = file_size - std::min(file_size, h.data_offset);
  const std::uint64_t need = out.points * point_size;  // points < 2^64 / 2^20: fits
  check_body_start(path, h.data_offset);
  if (data == "binary") {
    if (need > body)
      fail(path, "the header promises " + std::to_string(out.points) + " points of " + std::to_string(point_size) +
                     " bytes (" + std::to_string(need) + " bytes) but the file holds " + std::to_string(body) +
                     " bytes of data (truncated?)");
    // A body longer than promised means the header does not describe it (fields or sizes wrong).
    if (body > need)
      fail(path, "the header promises " + std::to_string(out.points) + " points of " + std::to_string(point_size) +
                     " bytes (" + std::to_string(need) + " bytes) but the file holds " + std::to_string(body - need) +
                     " bytes more after the header");
  } else if (data == "binary_compressed") {
    if (out.points == 0) return out;
    std::uint32_t sizes_of_block[2] = {0, 0};
    if (body < sizeof sizes_of_block || !in.read(reinterpret_cast<char*>(sizes_of_block), sizeof sizes_of_block))
      fail(path, "the compressed data block is missing (truncated?)");
    if (sizes_of_block[1] != need)
      fail(path, "the compressed block unpacks to " + std::to_string(sizes_of_block[1]) + " bytes, but " +
                     std::to_string(out.points) + " points of " + std::to_string(point_size) + " bytes need " +
                     std::to_string(need));
    if (sizes_of_block[0] > body - sizeof sizes_of_block)
      fail(path, "the compressed block has " + std::to_string(sizes_of_block[0]) + " bytes but the file holds " +
                     std::to_string(body - sizeof sizes_of_block) + " (truncated?)");
  } else if (data == "ascii") {
    std::vector<AsciiField> columns;
    for (std::size_t i = 0; i < fields.size(); ++i)
      for (std::uint64_t c = 0; c < counts[i]; ++c) columns.push_back({fields[i], types[i][0], sizes[i]});
    check_ascii_rows(path, in, h.lines.size(), out.points, columns);
  } else {
    fail(path, "DATA is '" + data + "', not ascii, binary or binary_compressed");
  }
  return out;
}

std::uint64_t ply_type_size(const std::string& t) {
  if (t == "char" || t == "uchar" || t == "int8" || t == "uint8") return 1;
  if (t == "short" || t == "ushort" || t == "int16" || t == "uint16") return 2;
  if (t == "int" || t == "uint" || t == "float" || t == "int32" || t == "uint32" || t == "float32") return 4;
  if (t == "double" || t == "float64") return 8;
  return 0;
}

CloudHeader check_ply(const std::string& path, std::uint64_t file_size) {
  std::ifstream in(path, std::ios::binary);
  std::string first;
  if (!std::getline(in, first) || (first != "ply" && first != "ply\r")) fail(path, "not a PLY file (no 'ply' line)");
  in.seekg(0);
  const HeaderLines h = read_header(path, in, "end_header");
  const std::uint64_t body = file_size - std::min(file_size, h.data_offset);
  CloudHeader out;
  bool binary = false, in_vertex = false, vertex_has_list = false, seen_vertex = false;
  std::uint64_t vertex_size = 0, elements = 0;
  int xyz = 0;
  for (std::size_t i = 1; i < h.lines.size(); ++i) {
    const auto w = words(h.lines[i]);
    if (!w.empty() && w[0] == "comment") out.comments.push_back(after_marker(h.lines[i], h.lines[i].find("comment") + 7));
    if (w.empty() || w[0] == "comment" || w[0] == "obj_info" || w[0] == "end_header") continue;
    if (w[0] == "format") {
      if (w.size() != 3) fail(path, "bad format line '" + h.lines[i] + "'");
      if (w[1] == "binary_little_endian" || w[1] == "binary_big_endian")
        binary = true;
      else if (w[1] != "ascii")
        fail(path, "format '" + w[1] + "' is not ascii, binary_little_endian or binary_big_endian");
    } else if (w[0] == "element") {
      if (w.size() != 3) fail(path, "bad element line '" + h.lines[i] + "'");
      const auto n = whole_number(w[2]);
      if (!n) fail(path, "element '" + w[1] + "' count '" + w[2] + "' is not a whole number >= 0");
      // Every element takes at least one byte of the body (binary) or one line (ASCII).
      if (*n > body) fail(path, "element '" + w[1] + "' count " + w[2] + " is more than the " + std::to_string(body) + " bytes of data can hold (truncated?)");
      elements += *n;
      in_vertex = w[1] == "vertex";
      if (in_vertex) {
        seen_vertex = true;
        out.points = *n;
      }
    } else if (w[0] == "property") {
      if (w.size() == 5 && w[1] == "list") {
        if (ply_type_size(w[2]) == 0 || ply_type_size(w[3]) == 0) fail(path, "bad list property '" + h.lines[i] + "'");
        if (in_vertex) vertex_has_list = true;
      } else if (w.size() == 3) {
        const std::uint64_t s = ply_type_size(w[1]);
        if (s == 0) fail(path, "property '" + w[2] + "' has unknown type '" + w[1] + "'");
        if (in_vertex) {
          vertex_size += s;
          if (w[2] == "x" || w[2] == "y" || w[2] == "z") ++xyz;
        }
      } else {
        fail(path, "bad property line '" + h.lines[i] + "'");
      }
    } else {
      fail(path, "unknown header line '" + h.lines[i] + "'");
    }
  }
  if (!seen_vertex) fail(path, "no vertex element");
  if (xyz != 3) fail(path, "the vertex element has no x, y and z properties");
  if (binary && !vertex_has_list && out.points * vertex_size > body)
    fail(path, "the header promises " + std::to_string(out.points) + " vertices of " + std::to_string(vertex_size) +
                   " bytes but the file holds " + std::to_string(body) + " bytes of data (truncated?)");
  if (!binary && elements > 0 && lines_after(in, elements) + 1 < elements)
    fail(path, "the header promises " + std::to_string(elements) + " elements but the file has fewer lines (truncated?)");
  return out;
}

}  // namespace

CloudHeader check_cloud_file(const std::string& path) {
  std::error_code ec;
  if (!std::filesystem::is_regular_file(path, ec)) fail(path, ec ? ec.message() : "not a regular file");
  const std::uint64_t size = std::filesystem::file_size(path, ec);
  if (ec) fail(path, ec.message());
  const std::string ext = extension(path);
  if (ext == ".pcd") return check_pcd(path, size);
  if (ext == ".ply") return check_ply(path, size);
  fail(path, "unsupported cloud format (use .pcd or .ply)");
}

void blob_to_xyzi(const pcl::PCLPointCloud2& blob, float missing_intensity, const std::string& path,
                  pcl::PointCloud<pcl::PointXYZI>& out, std::optional<ColorMatrix>& colors) {
  try {
    pointcloud2_to_xyzi(blob, out, missing_intensity);
    colors = pointcloud2_colors(blob);
  } catch (const std::invalid_argument& e) {
    const std::string what = e.what();
    fail(path, what.rfind("iwlomap: ", 0) == 0 ? what.substr(9) : what);
  }
}

}  // namespace iwlomap::tool
