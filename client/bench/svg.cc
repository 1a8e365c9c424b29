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

}  // namespace

std::string Render(const Figure& fig) {
  const double W = fig.width, H = fig.panel_height, L = 70, R = 20, T = 30, B = 40;
  const double head = fig.title.empty() ? 0 : 24;
  std::string s;
  double notes_h = 0;
  for (const Panel& p : fig.panels) notes_h += 14.0 * static_cast<double>(p.notes.size());
  const double total_h = head + H * static_cast<double>(fig.panels.size()) + notes_h;
  s += Format(
      "<svg xmlns=\"http://www.w3.org/2000/svg\" width=\"%g\" height=\"%g\" "
      "font-family=\"sans-serif\" font-size=\"12\">\n<rect width=\"100%%\" height=\"100%%\" "
      "fill=\"white\"/>\n",
      W, total_h);
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
    const double pw = W - L - R, ph = H - T - B;
    auto X = [&](double v) { return L + pw * std::clamp(ax.Map(v), -0.02, 1.02); };
    auto Y = [&](double v) { return top + ph * (1 - std::clamp(ay.Map(v), -0.02, 1.02)); };
    s += Format("<text x=\"%g\" y=\"%g\" font-weight=\"bold\">", L, y0 + 18) + Escape(p.title) +
         "</text>\n";
    for (std::size_t i = 0; i < p.notes.size(); ++i) {
      s += Format("<text x=\"%g\" y=\"%g\" font-size=\"11\">", L, y0 + 32 + 14.0 * i) +
           Escape(p.notes[i]) + "</text>\n";
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
    double legend_y = top + 14;
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
          s += Format("<circle cx=\"%.1f\" cy=\"%.1f\" r=\"%g\" fill=\"%s\"%s/>\n", X(se.x[i]),
                      Y(se.y[i]), big ? 5.5 : 3.5, se.color.c_str(),
                      big ? " stroke=\"black\" stroke-width=\"2\"" : "");
          if (i < se.point_labels.size() && !se.point_labels[i].empty()) {
            s += Format("<text x=\"%.1f\" y=\"%.1f\" font-size=\"9\" fill=\"%s\">", X(se.x[i]) + 6,
                        Y(se.y[i]) - 4, se.color.c_str()) +
                 Escape(se.point_labels[i]) + "</text>\n";
          }
        }
      }
      if (!se.label.empty()) {
        s += Format("<rect x=\"%g\" y=\"%g\" width=\"10\" height=\"10\" fill=\"%s\"/>\n",
                    L + pw - 200, legend_y - 9, se.color.c_str());
        s += Format("<text x=\"%g\" y=\"%g\">", L + pw - 185, legend_y) + Escape(se.label) +
             "</text>\n";
        legend_y += 15;
      }
    }
    y0 += H + 14.0 * static_cast<double>(p.notes.size());
  }
  s += "</svg>\n";
  return s;
}

void Write(const std::filesystem::path& path, const Figure& figure) {
  std::ofstream f(path);
  if (!f) throw std::runtime_error("cannot write " + path.string());
  f << Render(figure);
  if (!f) throw std::runtime_error("error writing " + path.string());
}

}  // namespace hapticpd::svg
