// A small SVG plot writer (no plotting runtime needed): stacked panels of
// line and scatter series with linear or logarithmic axes. The legend sits
// right of the plot, off the data; point labels are placed where they
// overlap no other label or point, and those that fit nowhere are listed
// under the legend instead. Used by
// `hapticpd demo` (force traces) and `hapticpd-bench accuracy` (Pareto plots).
#pragma once

#include <filesystem>
#include <limits>
#include <string>
#include <utility>
#include <vector>

namespace hapticpd::svg {

struct Series {
  std::string label;  ///< legend text (empty: no legend entry)
  std::string color = "#1f5fbf";
  bool line = true;      ///< polyline; false: one marker per point
  bool connect = false;  ///< scatter only: also join the points in order
  std::vector<double> x, y;
  /// Scatter only, optional (same length as x): text next to each point.
  std::vector<std::string> point_labels;
  /// Scatter only, optional: points drawn as a larger ringed marker
  /// (e.g. the default setting).
  std::vector<bool> highlight;
};

struct Panel {
  std::string title;
  std::string x_label, y_label;
  bool log_x = false, log_y = false;
  /// Axis ranges; NaN (default) = from the data (linear axes start at 0).
  double x_min = std::numeric_limits<double>::quiet_NaN(), x_max = x_min;
  double y_min = x_min, y_max = x_min;
  std::vector<Series> series;
  std::vector<std::string> notes;  ///< extra lines under the title
  /// Shaded x intervals (e.g. where the probe is in contact), drawn behind
  /// the data, with one legend entry `band_label`.
  std::vector<std::pair<double, double>> bands;
  std::string band_label;
  /// Draws the Pareto frontier of all scatter points (none both faster, i.e.
  /// smaller x, and better, smaller y, than a frontier point) as a dashed
  /// staircase.
  bool pareto_frontier = false;
};

struct Figure {
  std::string title;  ///< first line of the file (e.g. date and command)
  double width = 760, panel_height = 220;
  std::vector<Panel> panels;
};

/// Renders the figure as an SVG document.
std::string Render(const Figure& figure);

/// Writes Render(figure) to `path`; throws std::runtime_error naming the
/// file on failure.
void Write(const std::filesystem::path& path, const Figure& figure);

}  // namespace hapticpd::svg
