// SPDX-License-Identifier: BSD-3-Clause
#include "snapshot_marks.h"

#include <vtkActor.h>
#include <vtkActor2D.h>
#include <vtkAxesActor.h>
#include <vtkCamera.h>
#include <vtkCaptionActor2D.h>
#include <vtkCellArray.h>
#include <vtkGlyph3DMapper.h>
#include <vtkNew.h>
#include <vtkPoints.h>
#include <vtkPolyData.h>
#include <vtkPolyDataMapper.h>
#include <vtkPolyDataMapper2D.h>
#include <vtkProperty.h>
#include <vtkProperty2D.h>
#include <vtkRenderWindow.h>
#include <vtkRenderer.h>
#include <vtkSphereSource.h>
#include <vtkTextActor.h>
#include <vtkTextProperty.h>

#include <cmath>
#include <cstdio>
#include <string>

namespace iwlomap::viewer::detail {

double round_scale_length(double metres) {
  if (!(metres > 0.0) || !std::isfinite(metres)) return 1.0;
  const double decade = std::pow(10.0, std::floor(std::log10(metres)));
  for (const double m : {5.0, 2.0, 1.0})
    if (m * decade <= metres * (1.0 + 1e-9)) return m * decade;
  return decade;
}

void add_axes_triad(vtkRenderWindow* window, vtkCamera* map_camera, int size_px, int width, int height,
                    const Rgb& ink, int label_px) {
  vtkNew<vtkRenderer> corner;
  corner->SetLayer(2);
  corner->SetViewport(0.0, 0.0, static_cast<double>(size_px) / width, static_cast<double>(size_px) / height);
  vtkNew<vtkAxesActor> axes;
  axes->SetTotalLength(1.0, 1.0, 1.0);
  axes->SetShaftTypeToCylinder();
  axes->SetCylinderRadius(0.04);
  axes->SetConeRadius(0.5);
  const Rgb colours[3] = {{0.85, 0.15, 0.1}, {0.1, 0.62, 0.15}, {0.15, 0.3, 0.9}};
  vtkProperty* shafts[3] = {axes->GetXAxisShaftProperty(), axes->GetYAxisShaftProperty(), axes->GetZAxisShaftProperty()};
  vtkProperty* tips[3] = {axes->GetXAxisTipProperty(), axes->GetYAxisTipProperty(), axes->GetZAxisTipProperty()};
  vtkCaptionActor2D* captions[3] = {axes->GetXAxisCaptionActor2D(), axes->GetYAxisCaptionActor2D(),
                                    axes->GetZAxisCaptionActor2D()};
  for (int i = 0; i < 3; ++i) {
    shafts[i]->SetColor(colours[i].r, colours[i].g, colours[i].b);
    tips[i]->SetColor(colours[i].r, colours[i].g, colours[i].b);
    vtkTextProperty* tp = captions[i]->GetCaptionTextProperty();
    tp->SetColor(ink.r, ink.g, ink.b);
    tp->ShadowOff();
    tp->ItalicOff();
    tp->BoldOn();
    tp->SetFontSize(label_px);
    captions[i]->GetTextActor()->SetTextScaleModeToNone();
  }
  corner->AddActor(axes);
  // The map camera's direction and up, looking at the triad's origin from outside it.
  double dir[3], up[3];
  map_camera->GetDirectionOfProjection(dir);
  map_camera->GetViewUp(up);
  vtkCamera* c = corner->GetActiveCamera();
  c->SetFocalPoint(0.3, 0.3, 0.3);
  c->SetPosition(0.3 - 5.0 * dir[0], 0.3 - 5.0 * dir[1], 0.3 - 5.0 * dir[2]);
  c->SetViewUp(up);
  c->ParallelProjectionOn();
  c->SetParallelScale(1.05);
  corner->ResetCameraClippingRange();
  window->AddRenderer(corner);
}

void add_scale_bar(vtkRenderer* front, double metres_per_pixel, int map_width_px, int x_px, int y_px, const Rgb& ink,
                   int label_px) {
  const double metres = round_scale_length(0.2 * map_width_px * metres_per_pixel);
  const double length_px = metres / metres_per_pixel;
  const double tick = std::max(4.0, label_px * 0.45);
  // A bar with end ticks: |_____|
  vtkNew<vtkPoints> points;
  points->InsertNextPoint(x_px, y_px + tick, 0.0);
  points->InsertNextPoint(x_px, y_px, 0.0);
  points->InsertNextPoint(x_px + length_px, y_px, 0.0);
  points->InsertNextPoint(x_px + length_px, y_px + tick, 0.0);
  vtkNew<vtkCellArray> lines;
  lines->InsertNextCell(4);
  for (vtkIdType i = 0; i < 4; ++i) lines->InsertCellPoint(i);
  vtkNew<vtkPolyData> bar;
  bar->SetPoints(points);
  bar->SetLines(lines);
  vtkNew<vtkPolyDataMapper2D> mapper;
  mapper->SetInputData(bar);
  vtkNew<vtkActor2D> actor;
  actor->SetMapper(mapper);
  actor->GetProperty()->SetColor(ink.r, ink.g, ink.b);
  actor->GetProperty()->SetLineWidth(2.0f);
  front->AddActor2D(actor);

  char text[32];
  if (metres >= 1.0)
    std::snprintf(text, sizeof text, "%g m", metres);
  else
    std::snprintf(text, sizeof text, "%g cm", metres * 100.0);
  vtkNew<vtkTextActor> label;
  label->SetInput(text);
  vtkTextProperty* tp = label->GetTextProperty();
  tp->SetFontSize(label_px);
  tp->SetColor(ink.r, ink.g, ink.b);
  tp->SetJustificationToCentered();
  tp->SetVerticalJustificationToBottom();
  tp->ShadowOff();
  label->SetDisplayPosition(static_cast<int>(std::lround(x_px + length_px / 2.0)),
                            static_cast<int>(std::lround(y_px + tick * 0.6)));
  front->AddActor2D(label);
}

void add_sensor_track(vtkRenderer* renderer, const Eigen::MatrixXd& positions, const Eigen::Vector3d& centre,
                      double marker_radius) {
  const Eigen::Index n = positions.rows();
  if (n == 0) return;
  const Rgb colour{0.12, 0.12, 0.14};
  vtkNew<vtkPoints> points;
  for (Eigen::Index i = 0; i < n; ++i)
    points->InsertNextPoint(positions(i, 0) - centre.x(), positions(i, 1) - centre.y(), positions(i, 2) - centre.z());
  vtkNew<vtkPolyData> track;
  track->SetPoints(points);
  if (n >= 2) {
    vtkNew<vtkCellArray> line;
    line->InsertNextCell(static_cast<int>(n));
    for (vtkIdType i = 0; i < static_cast<vtkIdType>(n); ++i) line->InsertCellPoint(i);
    track->SetLines(line);
    vtkNew<vtkPolyDataMapper> line_mapper;
    line_mapper->SetInputData(track);
    line_mapper->ScalarVisibilityOff();
    vtkNew<vtkActor> line_actor;
    line_actor->SetMapper(line_mapper);
    line_actor->GetProperty()->SetColor(colour.r, colour.g, colour.b);
    line_actor->GetProperty()->SetLineWidth(2.0f);
    line_actor->GetProperty()->LightingOff();
    renderer->AddActor(line_actor);
  }
  // Every position a small sphere when there are few (a long track is its line), the last (the
  // current one) twice as large.
  const auto spheres = [&](vtkPolyData* at, double radius) {
    vtkNew<vtkSphereSource> sphere;
    sphere->SetRadius(radius);
    sphere->SetThetaResolution(16);
    sphere->SetPhiResolution(12);
    vtkNew<vtkGlyph3DMapper> mapper;
    mapper->SetInputData(at);
    mapper->SetSourceConnection(sphere->GetOutputPort());
    mapper->ScalingOff();
    mapper->OrientOff();
    mapper->ScalarVisibilityOff();
    vtkNew<vtkActor> actor;
    actor->SetMapper(mapper);
    actor->GetProperty()->SetColor(colour.r, colour.g, colour.b);
    actor->GetProperty()->SetAmbient(0.4);
    renderer->AddActor(actor);
  };
  constexpr Eigen::Index kMarkedPositions = 20;
  vtkNew<vtkPolyData> all;
  all->SetPoints(points);
  if (n <= kMarkedPositions) spheres(all, marker_radius);
  vtkNew<vtkPoints> last_point;
  last_point->InsertNextPoint(points->GetPoint(static_cast<vtkIdType>(n - 1)));
  vtkNew<vtkPolyData> last;
  last->SetPoints(last_point);
  spheres(last, 2.0 * marker_radius);
}

}  // namespace iwlomap::viewer::detail
