#include "client/bench/svg.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <fstream>
#include <stdexcept>

namespace hapticpd::svg {

namespace {

std::string Escape(const std::string& s) {
  std::string out;
  for (char c : s) {
    switch (c) {
      case '<':
        out += "&lt;";
        break;
      case '>':
        out += "&gt;";
        break;
      case '&':
        out += "&amp;";
        break;
      case '"':
        out += "&quot;";
        break;
      default:
        out += c;
    }
  }
  return out;
}

std::string Format(const char* fmt, auto... args) {
  char buf[512];
  std::snprintf(buf, sizeof(buf), fmt, args...);
  return buf;
}

struct Axis {
  bool log = false;
  double lo = 0, hi = 1;
  double Map(double v) const {  // 0..1
    if (log) return (std::log10(std::max(v, 1e-300)) - lo) / (hi - lo);
    return (v - lo) / (hi - lo);
  }
  double Value(double u) const {
    return log ? std::pow(10.0, lo + u * (hi - lo)) : lo + u * (hi - lo);
  }
};

Axis MakeAxis(bool log, double fixed_lo, double fixed_hi,
              const std::vector<const std::vector<double>*>& data) {
  double lo = std::numeric_limits<double>::infinity(), hi = -lo;
  for (const auto* v : data) {
    for (double x : *v) {
      if (!std::isfinite(x) || (log && x <= 0)) continue;
      lo = std::min(lo, x);
      hi = std::max(hi, x);
    }
  }
  if (!std::isfinite(lo)) lo = hi = log ? 1 : 0;
  Axis a;
  a.log = log;
  if (log) {
    a.lo = std::floor(std::log10(std::isnan(fixed_lo) ? lo : fixed_lo));
    a.hi = std::ceil(std::log10(std::isnan(fixed_hi) ? hi : fixed_hi));
    if (a.hi <= a.lo) a.hi = a.lo + 1;
  } else {
    a.lo = std::isnan(fixed_lo) ? std::min(0.0, lo) : fixed_lo;
    a.hi = std::isnan(fixed_hi) ? (hi > a.lo ? a.lo + 1.1 * (hi - a.lo) : a.lo + 1) : fixed_hi;
  }
  return a;
}

struct Box {
  double x0, y0, x1, y1;
  bool Overlaps(const Box& o) const { return x0 < o.x1 && o.x0 < x1 && y0 < o.y1 && o.y0 < y1; }
};

// Approximate extent of `text` at `font_size` px (sans-serif averages about
// 0.58 em per character).
double TextWidth(const std::string& text, double font_size) {
  return 0.58 * font_size * static_cast<double>(text.size());
}

// The points of every scatter series not dominated by another (smaller or
// equal x and y, one of them strictly), sorted by x.
std::vector<std::pair<double, double>> ParetoFrontier(const Panel& p) {
  std::vector<std::pair<double, double>> pts;
  for (const Series& se : p.series) {
    if (se.line) continue;
    for (std::size_t i = 0; i < std::min(se.x.size(), se.y.size()); ++i) {
      if (std::isfinite(se.x[i]) && std::isfinite(se.y[i])) pts.emplace_back(se.x[i], se.y[i]);
    }
  }
  std::sort(pts.begin(), pts.end());
  std::vector<std::pair<double, double>> front;
  for (const auto& q : pts) {
    if (front.empty() || q.second < front.back().second) {
      if (!front.empty() && front.back().first == q.first) front.pop_back();
      front.push_back(q);
    }
  }
  return front;
}

}  // namespace

std::string Render(const Figure& fig) {
  const double W = fig.width, H = fig.panel_height, L = 70, T = 30, B = 40;
  const double head = fig.title.empty() ? 0 : 24;
  std::string s;  // the panels; the header follows once their height is known
  if (!fig.title.empty()) {
    s += "<title>" + Escape(fig.title) + "</title>\n";
    s += Format("<text x=\"%g\" y=\"16\" font-size=\"11\" fill=\"#444\">", L) + Escape(fig.title) +
         "</text>\n";
  }
  double y0 = head;
  for (const Panel& p : fig.panels) {
    std::vector<const std::vector<double>*> xs, ys;
    for (const Series& se : p.series) {
      xs.push_back(&se.x);
      ys.push_back(&se.y);
    }
    const Axis ax = MakeAxis(p.log_x, p.x_min, p.x_max, xs);
    const Axis ay = MakeAxis(p.log_y, p.y_min, p.y_max, ys);
    const double top = y0 + T + 14.0 * static_cast<double>(p.notes.size());
    // The legend (and labels that fit nowhere on the plot) go right of it.
    double legend_w = 0;
    if (!p.band_label.empty()) legend_w = TextWidth(p.band_label, 12);
    if (p.pareto_frontier) legend_w = std::max(legend_w, TextWidth("Pareto frontier", 12));
    for (const Series& se : p.series) legend_w = std::max(legend_w, TextWidth(se.label, 12));
    const double R = legend_w > 0 ? std::clamp(legend_w + 40, 200.0, 0.45 * W) : 20;
    const double pw = W - L - R, ph = H - T - B;
    auto X = [&](double v) { return L + pw * std::clamp(ax.Map(v), -0.02, 1.02); };
    auto Y = [&](double v) { return top + ph * (1 - std::clamp(ay.Map(v), -0.02, 1.02)); };
    s += Format("<text x=\"%g\" y=\"%g\" font-weight=\"bold\">", L, y0 + 18) + Escape(p.title) +
         "</text>\n";
    for (std::size_t i = 0; i < p.notes.size(); ++i) {
      s += Format("<text x=\"%g\" y=\"%g\" font-size=\"11\">", L, y0 + 32 + 14.0 * i) +
           Escape(p.notes[i]) + "</text>\n";
    }
    for (const auto& [b0, b1] : p.bands) {
      const double x0 = X(b0), x1 = X(b1);
      if (x1 > x0) {
        s += Format("<rect x=\"%.1f\" y=\"%g\" width=\"%.1f\" height=\"%g\" fill=\"#f3e3b5\"/>\n",
                    x0, top, x1 - x0, ph);
      }
    }
    s += Format(
        "<rect x=\"%g\" y=\"%g\" width=\"%g\" height=\"%g\" fill=\"none\" stroke=\"#888\"/>\n", L,
        top, pw, ph);
    const int ticks_x = p.log_x ? static_cast<int>(ax.hi - ax.lo) : 4;
    const int ticks_y = p.log_y ? static_cast<int>(ay.hi - ay.lo) : 4;
    for (int i = 0; i <= ticks_x; ++i) {
      const double u = static_cast<double>(i) / ticks_x;
      s += Format("<text x=\"%g\" y=\"%g\" text-anchor=\"middle\">%.3g</text>\n", L + pw * u,
                  top + ph + 16, ax.Value(u));
    }
    for (int i = 0; i <= ticks_y; ++i) {
      const double u = static_cast<double>(i) / ticks_y;
      s += Format("<text x=\"%g\" y=\"%g\" text-anchor=\"end\">%.3g</text>\n", L - 4,
                  top + ph * (1 - u) + 4, ay.Value(u));
      if (i > 0 && i < ticks_y) {
        s += Format("<line x1=\"%g\" y1=\"%g\" x2=\"%g\" y2=\"%g\" stroke=\"#eee\"/>\n", L,
                    top + ph * (1 - u), L + pw, top + ph * (1 - u));
      }
    }
    if (!p.x_label.empty()) {
      s += Format("<text x=\"%g\" y=\"%g\" text-anchor=\"middle\">", L + pw / 2, top + ph + 32) +
           Escape(p.x_label) + "</text>\n";
    }
    if (!p.y_label.empty()) {
      s += Format("<text transform=\"translate(14,%g) rotate(-90)\" text-anchor=\"middle\">",
                  top + ph / 2) +
           Escape(p.y_label) + "</text>\n";
    }
    const double legend_x = L + pw + 12;
    double legend_y = top + 10;
    auto legend_entry = [&](const std::string& swatch, const std::string& text) {
      s += swatch;
      s += Format("<text x=\"%g\" y=\"%g\">", legend_x + 15, legend_y) + Escape(text) + "</text>\n";
      legend_y += 15;
    };
    if (!p.band_label.empty()) {
      legend_entry(Format("<rect x=\"%g\" y=\"%g\" width=\"10\" height=\"10\" fill=\"#f3e3b5\" "
                          "stroke=\"#d9c27a\"/>\n",
                          legend_x, legend_y - 9),
                   p.band_label);
    }
    if (p.pareto_frontier) {
      const auto front = ParetoFrontier(p);
      if (!front.empty()) {
        // A staircase: from each frontier point right to the next one's x,
        // then down to it (what is achievable at a given time budget).
        s += "<polyline fill=\"none\" stroke=\"#555\" stroke-width=\"1\" "
             "stroke-dasharray=\"4,3\" points=\"";
        for (std::size_t i = 0; i < front.size(); ++i) {
          if (i > 0) s += Format("%.1f,%.1f ", X(front[i].first), Y(front[i - 1].second));
          s += Format("%.1f,%.1f ", X(front[i].first), Y(front[i].second));
        }
        s += "\"/>\n";
      }
      legend_entry(Format("<line x1=\"%g\" y1=\"%g\" x2=\"%g\" y2=\"%g\" stroke=\"#555\" "
                          "stroke-dasharray=\"4,3\"/>\n",
                          legend_x, legend_y - 4, legend_x + 10, legend_y - 4),
                   "Pareto frontier");
    }
    // Markers first, then the labels, each at the first of eight spots
    // around its point that overlaps no marker, no placed label and stays
    // inside the plot.
    std::vector<Box> taken;
    for (const Series& se : p.series) {
      const std::size_t n = std::min(se.x.size(), se.y.size());
      if (se.line || se.connect) {
        s += "<polyline fill=\"none\" stroke=\"" + se.color + "\" stroke-width=\"1.2\" points=\"";
        const std::size_t step = se.line ? std::max<std::size_t>(1, n / 1500) : 1;
        for (std::size_t i = 0; i < n; i += step) s += Format("%.1f,%.1f ", X(se.x[i]), Y(se.y[i]));
        s += "\"/>\n";
      }
      if (!se.line) {
        for (std::size_t i = 0; i < n; ++i) {
          const bool big = i < se.highlight.size() && se.highlight[i];
          const double r = big ? 5.5 : 3.5;
          s += Format("<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%g\" fill=\"%s\"%s/>\n", X(se.x[i]),
                      Y(se.y[i]), r, se.color.c_str(),
                      big ? " stroke=\"black\" stroke-width=\"2\"" : "");
          taken.push_back({X(se.x[i]) - r, Y(se.y[i]) - r, X(se.x[i]) + r, Y(se.y[i]) + r});
        }
      }
      if (!se.label.empty()) {
        legend_entry(Format("<rect x=\"%g\" y=\"%g\" width=\"10\" height=\"10\" fill=\"%s\"/>\n",
                            legend_x, legend_y - 9, se.color.c_str()),
                     se.label);
      }
    }
    constexpr double kLabelFont = 9;
    std::vector<std::pair<std::string, std::string>> unplaced;  // text, colour
    for (const Series& se : p.series) {
      if (se.line) continue;
      const std::size_t n = std::min({se.x.size(), se.y.size(), se.point_labels.size()});
      for (std::size_t i = 0; i < n; ++i) {
        const std::string& text = se.point_labels[i];
        if (text.empty()) continue;
        const double px = X(se.x[i]), py = Y(se.y[i]);
        const double w = TextWidth(text, kLabelFont), h = kLabelFont + 2;
        const double spots[8][2] = {{7, -h - 2}, {7, 2},           {-7 - w, -h - 2},
                                    {-7 - w, 2}, {-w / 2, -h - 7}, {-w / 2, 7},
                                    {9, -h / 2}, {-9 - w, -h / 2}};
        bool placed = false;
        for (const auto& d : spots) {
          const Box box{px + d[0], py + d[1], px + d[0] + w, py + d[1] + h};
          if (box.x0 < L || box.x1 > L + pw || box.y0 < top || box.y1 > top + ph) continue;
          if (std::any_of(taken.begin(), taken.end(),
                          [&](const Box& t) { return t.Overlaps(box); })) {
            continue;
          }
          taken.push_back(box);
          s += Format("<text x=\"%.1f\" y=\"%.1f\" font-size=\"%g\" fill=\"%s\">", box.x0,
                      box.y1 - 2, kLabelFont, se.color.c_str()) +
               Escape(text) + "</text>\n";
          placed = true;
          break;
        }
        if (!placed) {
          unplaced.emplace_back(text + Format(" (%.3g, %.3g)", se.x[i], se.y[i]), se.color);
        }
      }
    }
    if (!unplaced.empty()) {
      legend_y += 6;
      s += Format("<text x=\"%g\" y=\"%g\" font-size=\"10\" fill=\"#444\">", legend_x, legend_y) +
           "crowded points (x, y):</text>\n";
      for (const auto& [text, color] : unplaced) {
        legend_y += 12;
        s += Format("<text x=\"%g\" y=\"%g\" font-size=\"%g\" fill=\"%s\">", legend_x, legend_y,
                    kLabelFont, color.c_str()) +
             Escape(text) + "</text>\n";
      }
    }
    // A long list beside the plot makes the panel taller.
    y0 = std::max(y0 + H + 14.0 * static_cast<double>(p.notes.size()), legend_y + 10);
  }
  return Format(
             "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%g\" height=\"%g\" "
             "font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%%\" "
             "height=\"100%%\" fill=\"white\"/>\n",
             W, y0) +
         s + "</svg>\n";
}

void Write(const std::filesystem::path& path, const Figure& figure) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write " + path.string());
  f << Render(figure);
  if (!f) throw std::runtime_error("error writing " + path.string());
}

}  // namespace hapticpd::svg
