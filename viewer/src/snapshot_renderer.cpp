// SPDX-License-Identifier: BSD-3-Clause
#include "iwlomap/viewer/snapshot_renderer.h"

#include "snapshot_marks.h"
#include "vtk_errors.h"
#include "x_display.h"

#include <Eigen/Geometry>
#include <vtkActor.h>
#include <vtkCamera.h>
#include <vtkCellArray.h>
#include <vtkCubeSource.h>
#include <vtkFloatArray.h>
#include <vtkGlyph3DMapper.h>
#include <vtkImageData.h>
#include <vtkLight.h>
#include <vtkLookupTable.h>
#include <vtkNew.h>
#include <vtkPointData.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkProperty.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkScalarBarActor.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>
#include <vtkUnsignedCharArray.h>
#include <vtkWindowToImageFilter.h>

#include <algorithm>
#include <array>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <mutex>
#include <stdexcept>
#include <string>
#include <vector>

namespace iwlomap::viewer {

namespace {

// The map's bounding box fills this fraction of the view's limiting dimension (parallel views).
constexpr double kFill = 0.9;
constexpr double kPerspectiveAngleDeg = 30.0;
constexpr double kPi = 3.14159265358979323846;
// Iso preset: azimuth measured from +x towards +y, elevation above the horizon. A steeper look
// than the 35.3 degrees of a true isometric view shows the floor between walls.
constexpr double kIsoAzimuthDeg = -55.0;
constexpr double kIsoElevationDeg = 50.0;

std::string num(double v) {
  char buf[32];
  std::snprintf(buf, sizeof buf, "%.17g", v);
  return buf;
}

/// Voxels that can be drawn, in coordinates relative to the centre of their bounding box (float
/// precision is then enough even for survey coordinates in the millions of metres).
struct Scene {
  std::vector<Eigen::Index> rows;       // rows of the input that are drawn
  Eigen::Vector3d box_min, box_max;     // bounding box of the cubes, map frame
  Eigen::Vector3d centre;               // centre of that box, the rendering origin
  double z_min = 0.0, z_max = 0.0;      // voxel centres
};

Scene collect(const Eigen::MatrixXd& v, double resolution, bool need_probability, const Eigen::MatrixXd& sensors) {
  Scene s;
  s.rows.reserve(static_cast<std::size_t>(v.rows()));
  Eigen::Vector3d lo = Eigen::Vector3d::Constant(std::numeric_limits<double>::infinity());
  Eigen::Vector3d hi = -lo;
  for (Eigen::Index i = 0; i < v.rows(); ++i) {
    const double x = v(i, 0), y = v(i, 1), z = v(i, 2);
    if (!std::isfinite(x) || !std::isfinite(y) || !std::isfinite(z)) continue;
    if (need_probability && !std::isfinite(v(i, 3))) continue;
    s.rows.push_back(i);
    lo = lo.cwiseMin(Eigen::Vector3d(x, y, z));
    hi = hi.cwiseMax(Eigen::Vector3d(x, y, z));
  }
  // The sensor positions are framed with the voxels.
  for (Eigen::Index i = 0; i < sensors.rows(); ++i) {
    lo = lo.cwiseMin(sensors.row(i).transpose());
    hi = hi.cwiseMax(sensors.row(i).transpose());
  }
  if (s.rows.empty() && sensors.rows() == 0) {
    // Nothing to frame: a cube of one metre around the origin keeps the camera maths finite.
    s.box_min = Eigen::Vector3d::Constant(-0.5);
    s.box_max = Eigen::Vector3d::Constant(0.5);
    s.z_min = 0.0;
    s.z_max = 0.0;
  } else {
    s.z_min = lo.z();
    s.z_max = hi.z();
    if (!s.rows.empty()) {  // the colour range: voxel centres only
      s.z_min = std::numeric_limits<double>::infinity();
      s.z_max = -s.z_min;
      for (const Eigen::Index i : s.rows) {
        s.z_min = std::min(s.z_min, v(i, 2));
        s.z_max = std::max(s.z_max, v(i, 2));
      }
    }
    s.box_min = lo.array() - resolution / 2.0;
    s.box_max = hi.array() + resolution / 2.0;
  }
  s.centre = (s.box_min + s.box_max) / 2.0;
  return s;
}

/// The value range spread over the colour map.
std::pair<double, double> color_range(const SnapshotOptions& o, const Scene& s, double resolution) {
  double lo = 0.0, hi = 1.0;
  if (o.color_by == ColorBy::kProbability) {
    lo = 0.5;
    hi = 1.0;
  } else if (!s.rows.empty()) {
    lo = s.z_min;
    hi = s.z_max;
    // A flat map gets one voxel of range, so it shows the middle colour and the bar stays readable.
    if (hi == lo) {
      lo -= resolution / 2.0;
      hi += resolution / 2.0;
    }
  }
  if (o.color_min) lo = *o.color_min;
  if (o.color_max) hi = *o.color_max;
  if (!(lo < hi))
    throw std::invalid_argument("SnapshotRenderer: the colour range [" + num(lo) + ", " + num(hi) +
                                "] is empty; set both color_min and color_max");
  return {lo, hi};
}

vtkSmartPointer<vtkPolyData> make_polydata(const Eigen::MatrixXd& v, const Scene& s, const SnapshotOptions& o,
                                           const ColorMap& cmap, double lo, double hi, bool with_vertices) {
  const auto n = static_cast<vtkIdType>(s.rows.size());
  vtkNew<vtkFloatArray> coords;
  coords->SetNumberOfComponents(3);
  coords->SetNumberOfTuples(n);
  float* xyz = coords->WritePointer(0, 3 * n);
  vtkNew<vtkUnsignedCharArray> colors;
  colors->SetName("colors");
  colors->SetNumberOfComponents(3);
  colors->SetNumberOfTuples(n);
  std::uint8_t* rgb = colors->WritePointer(0, 3 * n);
  const auto fixed = to_rgb8(o.fixed_color);
  for (vtkIdType k = 0; k < n; ++k) {
    const Eigen::Index i = s.rows[static_cast<std::size_t>(k)];
    xyz[3 * k] = static_cast<float>(v(i, 0) - s.centre.x());
    xyz[3 * k + 1] = static_cast<float>(v(i, 1) - s.centre.y());
    xyz[3 * k + 2] = static_cast<float>(v(i, 2) - s.centre.z());
    std::array<std::uint8_t, 3> c = fixed;
    if (o.color_by == ColorBy::kProbability)
      c = to_rgb8(cmap.map(v(i, 3), lo, hi));
    else if (o.color_by == ColorBy::kHeight)
      c = to_rgb8(cmap.map(v(i, 2), lo, hi));
    else if (o.color_by == ColorBy::kRgb)
      c = {o.voxel_rgb(i, 0), o.voxel_rgb(i, 1), o.voxel_rgb(i, 2)};
    std::memcpy(rgb + 3 * k, c.data(), 3);
  }
  vtkNew<vtkPoints> points;
  points->SetData(coords);
  auto poly = vtkSmartPointer<vtkPolyData>::New();
  poly->SetPoints(points);
  poly->GetPointData()->SetScalars(colors);
  if (with_vertices) {
    // One vertex cell per point: offsets 0..n, connectivity 0..n-1.
    vtkNew<vtkCellArray> verts;
    verts->AllocateExact(n, n);
    for (vtkIdType k = 0; k < n; ++k) verts->InsertNextCell(1, &k);
    poly->SetVerts(verts);
  }
  return poly;
}

Eigen::Vector3d preset_direction(CameraPreset p) {  // from the target towards the eye
  switch (p) {
    case CameraPreset::kTop:
      return Eigen::Vector3d::UnitZ();
    case CameraPreset::kFront:
      return -Eigen::Vector3d::UnitY();
    case CameraPreset::kSide:
      return Eigen::Vector3d::UnitX();
    case CameraPreset::kIso:
      break;
  }
  const double az = kIsoAzimuthDeg * kPi / 180.0, el = kIsoElevationDeg * kPi / 180.0;
  return {std::cos(el) * std::cos(az), std::cos(el) * std::sin(az), std::sin(el)};
}

Eigen::Vector3d preset_up(CameraPreset p) { return p == CameraPreset::kTop ? Eigen::Vector3d::UnitY() : Eigen::Vector3d::UnitZ(); }

/// Points the camera and frames the scene (relative coordinates: the box is centred at 0). A
/// parallel view frames the cubes and sensor positions as the camera sees them, not the corners
/// of their bounding box, which stick out of the picture in oblique views.
void place_camera(vtkCamera* camera, const SnapshotOptions& o, const Scene& s, double aspect, const Eigen::MatrixXd& v,
                  double resolution) {
  const Eigen::Vector3d half = (s.box_max - s.box_min) / 2.0;
  const double radius = std::max(half.norm(), 1e-9);
  Eigen::Vector3d target = Eigen::Vector3d::Zero(), dir, up;
  if (o.camera_pose) {
    target = o.camera_pose->target - s.centre;
    dir = (o.camera_pose->eye - o.camera_pose->target).normalized();
    up = o.camera_pose->up;
  } else {
    dir = preset_direction(o.camera);
    up = preset_up(o.camera);
    if (o.z_down) {  // half a turn about +x: a proper rotation, so the image is not mirrored
      dir = Eigen::Vector3d(dir.x(), -dir.y(), -dir.z());
      up = Eigen::Vector3d(up.x(), -up.y(), -up.z());
    }
  }
  if (o.perspective && o.camera_pose) {
    const Eigen::Vector3d eye = o.camera_pose->eye - s.centre;
    camera->SetPosition(eye.x(), eye.y(), eye.z());
  } else {
    // A parallel view only depends on the direction; the eye goes outside the box so nothing is
    // clipped behind it. Perspective presets are moved back below, once the angle is known.
    const double back = (target.norm() + radius) * 2.0 + 1.0;
    const Eigen::Vector3d eye = target + dir * back;
    camera->SetPosition(eye.x(), eye.y(), eye.z());
  }
  camera->SetFocalPoint(target.x(), target.y(), target.z());
  camera->SetViewUp(up.x(), up.y(), up.z());
  camera->OrthogonalizeViewUp();

  if (o.perspective) {
    camera->ParallelProjectionOff();
    camera->SetViewAngle(kPerspectiveAngleDeg);
    if (!o.camera_pose) {
      // Far enough that the bounding sphere fits the narrower of the two view angles.
      const double half_v = kPerspectiveAngleDeg / 2.0 * kPi / 180.0;
      const double half_h = std::atan(std::tan(half_v) * aspect);
      const double dist = radius / std::sin(std::min(half_v, half_h)) / kFill;
      const Eigen::Vector3d eye = target + dir * dist;
      camera->SetPosition(eye.x(), eye.y(), eye.z());
    }
    return;
  }
  camera->ParallelProjectionOn();
  // Half extents of the box corners seen along the view, relative to the target.
  double vp[3], vu[3];
  camera->GetDirectionOfProjection(vp);
  camera->GetViewUp(vu);
  const Eigen::Vector3d view(vp[0], vp[1], vp[2]), cam_up(vu[0], vu[1], vu[2]);
  const Eigen::Vector3d right = view.cross(cam_up).normalized();
  double half_w = 0.0, half_h = 0.0;
  if (o.camera_pose) {  // the target stays at the centre: the box's corners around it
    for (int c = 0; c < 8; ++c) {
      const Eigen::Vector3d corner((c & 1) ? half.x() : -half.x(), (c & 2) ? half.y() : -half.y(),
                                   (c & 4) ? half.z() : -half.z());
      const Eigen::Vector3d rel = corner - target;
      half_w = std::max(half_w, std::abs(rel.dot(right)));
      half_h = std::max(half_h, std::abs(rel.dot(cam_up)));
    }
  } else {
    // Each cube's extent along the image axes (its centre's projection plus half an edge times the
    // axis' components), and each sensor position: the view is centred on what is drawn.
    const double cube_w = resolution / 2.0 * right.cwiseAbs().sum();
    const double cube_h = resolution / 2.0 * cam_up.cwiseAbs().sum();
    double lo_w = std::numeric_limits<double>::infinity(), hi_w = -lo_w, lo_h = lo_w, hi_h = -lo_w;
    const auto take = [&](const Eigen::Vector3d& p, double ew, double eh) {
      const double pw = p.dot(right), ph = p.dot(cam_up);
      lo_w = std::min(lo_w, pw - ew);
      hi_w = std::max(hi_w, pw + ew);
      lo_h = std::min(lo_h, ph - eh);
      hi_h = std::max(hi_h, ph + eh);
    };
    for (const Eigen::Index i : s.rows) take(Eigen::Vector3d(v(i, 0), v(i, 1), v(i, 2)) - s.centre, cube_w, cube_h);
    for (Eigen::Index i = 0; i < o.sensor_positions.rows(); ++i)
      take(o.sensor_positions.row(i).transpose() - s.centre, 0.0, 0.0);
    if (!(lo_w <= hi_w)) lo_w = hi_w = lo_h = hi_h = 0.0;  // nothing drawn
    half_w = std::max((hi_w - lo_w) / 2.0, 1e-9);
    half_h = std::max((hi_h - lo_h) / 2.0, 1e-9);
    // Slide the camera in its image plane onto the middle of what is drawn.
    const Eigen::Vector3d shift = right * ((lo_w + hi_w) / 2.0) + cam_up * ((lo_h + hi_h) / 2.0);
    double pos[3], focal[3];
    camera->GetPosition(pos);
    camera->GetFocalPoint(focal);
    camera->SetPosition(pos[0] + shift.x(), pos[1] + shift.y(), pos[2] + shift.z());
    camera->SetFocalPoint(focal[0] + shift.x(), focal[1] + shift.y(), focal[2] + shift.z());
  }
  camera->SetParallelScale(std::max({half_h, half_w / aspect, 1e-9}) / kFill);
}

void add_lights(vtkRenderer* renderer) {
  renderer->AutomaticLightCreationOff();
  renderer->RemoveAllLights();
  // Camera lights move with the view, so every preset and pose is lit the same way: a key light
  // above and to the right of the eye (cube faces facing different ways get different shades) and
  // a weak fill from the other side so no face is black.
  vtkNew<vtkLight> key;
  key->SetLightTypeToCameraLight();
  key->SetPosition(0.45, 0.8, 1.0);
  key->SetFocalPoint(0.0, 0.0, 0.0);
  key->SetIntensity(0.9);
  renderer->AddLight(key);
  vtkNew<vtkLight> fill;
  fill->SetLightTypeToCameraLight();
  fill->SetPosition(-0.7, -0.2, 0.6);
  fill->SetFocalPoint(0.0, 0.0, 0.0);
  fill->SetIntensity(0.3);
  renderer->AddLight(fill);
}

Rgb text_color_for(const Rgb& bg) {
  const double luma = 0.2126 * bg.r + 0.7152 * bg.g + 0.0722 * bg.b;
  return luma < 0.5 ? Rgb{0.93, 0.93, 0.93} : Rgb{0.08, 0.08, 0.08};
}

RgbImage render_scene(void* display, const Eigen::MatrixXd& v, double resolution, const SnapshotOptions& o,
                      const Scene& scene, double lo, double hi) {
  const ColorMap cmap = o.color_by == ColorBy::kProbability ? ColorMap::probability() : ColorMap::height();
  const bool points = o.shape == VoxelShape::kPoints;
  const auto poly = make_polydata(v, scene, o, cmap, lo, hi, points);

  vtkNew<detail::VtkErrorCollector> errors;
  vtkNew<vtkActor> actor;
  vtkNew<vtkCubeSource> cube;
  vtkSmartPointer<vtkMapper> mapper;
  if (points) {
    auto m = vtkSmartPointer<vtkPolyDataMapper>::New();
    m->SetInputData(poly);
    mapper = m;
    actor->GetProperty()->SetPointSize(static_cast<float>(o.point_size));
    actor->GetProperty()->SetRenderPointsAsSpheres(o.lighting);
  } else {
    cube->SetXLength(resolution);
    cube->SetYLength(resolution);
    cube->SetZLength(resolution);
    auto m = vtkSmartPointer<vtkGlyph3DMapper>::New();
    m->SetInputData(poly);
    m->SetSourceConnection(cube->GetOutputPort());
    m->ScalingOff();
    m->OrientOff();
    mapper = m;
  }
  mapper->ScalarVisibilityOn();
  mapper->SetScalarModeToUsePointData();
  mapper->SetColorModeToDirectScalars();
  errors->watch(mapper);
  actor->SetMapper(mapper);
  if (o.lighting) {
    actor->GetProperty()->SetAmbient(0.35);
    actor->GetProperty()->SetDiffuse(0.7);
    actor->GetProperty()->SetSpecular(0.0);
  } else {
    actor->GetProperty()->LightingOff();  // the voxel colours exactly as the colour map gives them
  }

  // Layout in pixels: the colour bar gets a band on the right, the title a band on top, and the
  // map is framed in what is left, so neither covers voxels.
  const int w = o.width, h = o.height;
  const bool bar = o.color_bar && o.color_by != ColorBy::kFixed && o.color_by != ColorBy::kRgb;
  const bool title = !o.title.empty();
  const int title_px = std::clamp(static_cast<int>(std::lround(h / 26.0)), 10, 72);
  const int label_px = std::clamp(static_cast<int>(std::lround(h / 48.0)), 9, 40);
  const int title_band = title ? static_cast<int>(std::lround(title_px * 1.9)) : 0;
  const int bar_band = bar ? std::min(w / 4, std::clamp(static_cast<int>(std::lround(w * 0.13)), 48, 300)) : 0;
  const double map_x1 = static_cast<double>(w - bar_band) / w;
  const double map_y1 = static_cast<double>(h - title_band) / h;
  const double map_aspect = (map_x1 * w) / (map_y1 * h);
  const Rgb ink = text_color_for(o.background);

  // Layer 0 clears to the background and carries the 2D overlays; layer 1 draws the map on top.
  vtkNew<vtkRenderer> overlay;
  overlay->SetLayer(0);
  overlay->SetBackground(o.background.r, o.background.g, o.background.b);
  vtkNew<vtkRenderer> renderer;
  renderer->SetLayer(1);
  renderer->SetViewport(0.0, 0.0, map_x1, map_y1);
  renderer->AddActor(actor);
  if (o.lighting) add_lights(renderer);
  place_camera(renderer->GetActiveCamera(), o, scene, map_aspect, v, resolution);
  // The sensor's positions: markers of about a hundredth of the scene, at least a voxel.
  detail::add_sensor_track(renderer, o.sensor_positions, scene.centre,
                           std::max(resolution, 0.006 * (scene.box_max - scene.box_min).norm()));
  const double rel_min[3] = {scene.box_min.x() - scene.centre.x(), scene.box_min.y() - scene.centre.y(),
                             scene.box_min.z() - scene.centre.z()};
  const double bounds[6] = {rel_min[0], -rel_min[0], rel_min[1], -rel_min[1], rel_min[2], -rel_min[2]};
  renderer->ResetCameraClippingRange(bounds);

  vtkNew<vtkTextActor> title_actor;
  if (title) {
    title_actor->SetInput(o.title.c_str());
    vtkTextProperty* tp = title_actor->GetTextProperty();
    tp->SetFontSize(title_px);
    tp->SetJustificationToCentered();
    tp->SetVerticalJustificationToCentered();
    tp->SetColor(ink.r, ink.g, ink.b);
    tp->BoldOn();
    title_actor->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
    title_actor->SetPosition(0.5, 1.0 - (title_band / 2.0) / h);
    overlay->AddActor2D(title_actor);
  }

  vtkNew<vtkLookupTable> lut;
  vtkNew<vtkScalarBarActor> bar_actor;
  if (bar) {
    const std::vector<Rgb> table = cmap.sample(256);
    lut->SetNumberOfTableValues(static_cast<vtkIdType>(table.size()));
    lut->Build();
    for (std::size_t i = 0; i < table.size(); ++i)
      lut->SetTableValue(static_cast<vtkIdType>(i), table[i].r, table[i].g, table[i].b, 1.0);
    lut->SetTableRange(lo, hi);
    bar_actor->SetLookupTable(lut);
    const std::string bar_title = !o.color_bar_title.empty()             ? o.color_bar_title
                                  : o.color_by == ColorBy::kProbability ? std::string("probability")
                                  : o.z_down                            ? std::string("depth (m)")
                                                                        : std::string("height (m)");
    bar_actor->SetTitle(bar_title.c_str());
    constexpr int kLabels = 5;
    bar_actor->SetNumberOfLabels(kLabels);
    const std::string label_format = "%." + std::to_string(label_decimals(lo, hi, kLabels)) + "f";
    bar_actor->SetLabelFormat(label_format.c_str());
    bar_actor->UnconstrainedFontSizeOn();
    bar_actor->SetBarRatio(0.28);
    // Keeps the title clear of the top label, which VTK centres on the end of the bar.
    bar_actor->SetVerticalTitleSeparation(label_px);
    bar_actor->SetTextPad(std::max(2, label_px / 4));
    bar_actor->SetMaximumWidthInPixels(bar_band);
    for (vtkTextProperty* tp : {bar_actor->GetLabelTextProperty(), bar_actor->GetTitleTextProperty()}) {
      tp->SetColor(ink.r, ink.g, ink.b);
      tp->ShadowOff();
      tp->ItalicOff();
      tp->SetFontSize(label_px);
    }
    bar_actor->GetTitleTextProperty()->BoldOn();
    bar_actor->GetPositionCoordinate()->SetCoordinateSystemToNormalizedViewport();
    bar_actor->SetPosition((w - bar_band * 0.92) / w, 0.1 * map_y1);
    bar_actor->SetPosition2(bar_band * 0.85 / w, 0.8 * map_y1);
    overlay->AddActor2D(bar_actor);
  }

  vtkNew<vtkRenderWindow> window;
  errors->watch(window);
  window->SetDisplayId(display);
  window->SetOffScreenRendering(1);
  window->SetMultiSamples(0);
  window->SetSize(w, h);
  window->SetNumberOfLayers(3);
  window->AddRenderer(overlay);
  window->AddRenderer(renderer);
  // Marks on top of the map, in its lower-left corner: the axes triad, then the scale bar.
  const int triad_px = std::clamp(static_cast<int>(std::lround(std::min(w, h) * 0.16)), 40, 260);
  if (o.axes)
    detail::add_axes_triad(window, renderer->GetActiveCamera(), triad_px, w, h, ink, label_px);
  vtkNew<vtkRenderer> front;
  front->SetLayer(2);
  front->InteractiveOff();
  if (o.scale_bar && !o.perspective) {
    const double map_h_px = map_y1 * h;
    const double metres_per_pixel = 2.0 * renderer->GetActiveCamera()->GetParallelScale() / map_h_px;
    detail::add_scale_bar(front, metres_per_pixel, static_cast<int>(map_x1 * w), (o.axes ? triad_px : 0) + label_px,
                          std::max(label_px, triad_px / 5), ink, label_px);
    window->AddRenderer(front);
  }
  // Edge smoothing after the fact: much cheaper than multisampling on a software rasteriser, and it
  // leaves the inside of flat regions untouched.
  renderer->UseFXAAOn();
  window->Render();

  vtkNew<vtkWindowToImageFilter> grab;
  errors->watch(grab);
  grab->SetInput(window);
  grab->SetInputBufferTypeToRGB();
  grab->ReadFrontBufferOff();
  grab->ShouldRerenderOff();
  grab->Update();
  if (errors->failed()) throw std::runtime_error("SnapshotRenderer: VTK failed to render: " + errors->messages());

  vtkImageData* out = grab->GetOutput();
  int dims[3] = {0, 0, 0};
  out->GetDimensions(dims);
  if (dims[0] != w || dims[1] != h || out->GetNumberOfScalarComponents() != 3)
    throw std::runtime_error("SnapshotRenderer: VTK returned a " + std::to_string(dims[0]) + " x " +
                             std::to_string(dims[1]) + " image with " +
                             std::to_string(out->GetNumberOfScalarComponents()) + " components, expected " +
                             std::to_string(w) + " x " + std::to_string(h) + " RGB");
  RgbImage image;
  image.width = w;
  image.height = h;
  image.rgb.resize(static_cast<std::size_t>(w) * static_cast<std::size_t>(h) * 3);
  const auto* src = static_cast<const std::uint8_t*>(out->GetScalarPointer());
  const std::size_t row = static_cast<std::size_t>(w) * 3;
  for (int y = 0; y < h; ++y)  // VTK's first row is the bottom one
    std::memcpy(image.rgb.data() + static_cast<std::size_t>(y) * row,
                src + static_cast<std::size_t>(h - 1 - y) * row, row);
  return image;
}

}  // namespace

RgbImage SnapshotRenderer::render(const Eigen::MatrixXd& voxels_xyzp, double resolution,
                                  const SnapshotOptions& options) {
  options.validate();
  if (voxels_xyzp.cols() != 4)
    throw std::invalid_argument("SnapshotRenderer: the voxel matrix has " + std::to_string(voxels_xyzp.cols()) +
                                " columns, expected 4 (x, y, z, p)");
  if (options.color_by == ColorBy::kRgb && options.voxel_rgb.rows() != voxels_xyzp.rows())
    throw std::invalid_argument("SnapshotRenderer: ColorBy::kRgb with " + std::to_string(options.voxel_rgb.rows()) +
                                " colours for " + std::to_string(voxels_xyzp.rows()) + " voxels");
  if (!(resolution > 0.0) || !std::isfinite(resolution))
    throw std::invalid_argument("SnapshotRenderer: resolution " + num(resolution) +
                                " is not a positive finite number of metres");
  // Everything that can be wrong with the input is reported before the display is needed.
  const Scene scene = collect(voxels_xyzp, resolution, options.color_by == ColorBy::kProbability, options.sensor_positions);
  const auto [lo, hi] = color_range(options, scene, resolution);
  // Xlib (without XInitThreads) and VTK's object factories are not thread-safe: one render at a time.
  static std::mutex one_at_a_time;
  const std::lock_guard<std::mutex> lock(one_at_a_time);
  // Declared before every VTK object (all of which live in render_scene), so it is closed last.
  const detail::XDisplay display = detail::XDisplay::open();
  return render_scene(display.get(), voxels_xyzp, resolution, options, scene, lo, hi);
}

void SnapshotRenderer::render_png(const Eigen::MatrixXd& voxels_xyzp, double resolution,
                                  const SnapshotOptions& options, const std::string& path) {
  write_png(render(voxels_xyzp, resolution, options), path);
}

RgbImage SnapshotRenderer::render(IMapperBackend& map, const SnapshotOptions& options, double min_probability) {
  const double threshold = min_probability < 0.0 ? map.get_params().occupied_threshold : min_probability;
  return render(map.get_occupied_voxels(threshold), map.get_resolution(), options);
}

void SnapshotRenderer::render_png(IMapperBackend& map, const SnapshotOptions& options, const std::string& path,
                                  double min_probability) {
  write_png(render(map, options, min_probability), path);
}

void SnapshotRenderer::check_display() { (void)detail::XDisplay::open(); }

}  // namespace iwlomap::viewer
