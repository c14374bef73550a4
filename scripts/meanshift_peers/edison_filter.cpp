// Times EDISON's mean-shift filter (Comaniciu & Meer's reference code, msImageProcessor::Filter:
// the filter, then connecting pixels of one mode into regions) on the colour images of
// images.py, one image after another on one core.
// Usage: edison_filter RGB.raw SIGMA_S SIGMA_R SPEEDUP(0 none, 1 medium, 2 high) RUNS
// Prints per run: total seconds, median returns/s per scan, regions.
#include "msImageProcessor.h"

#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <vector>

struct Image {
  int h, w, returns;
  std::vector<unsigned char> rgb;
};

int main(int argc, char** argv) {
  if (argc != 6) {
    fprintf(stderr, "usage: edison_filter RGB.raw SIGMA_S SIGMA_R SPEEDUP RUNS\n");
    return 2;
  }
  FILE* f = fopen(argv[1], "rb");
  int n = 0;
  if (!f || fread(&n, 4, 1, f) != 1) {
    fprintf(stderr, "edison_filter: cannot read %s\n", argv[1]);
    return 1;
  }
  std::vector<Image> imgs(n);
  for (auto& im : imgs) {
    int hdr[3];
    if (fread(hdr, 4, 3, f) != 3) return 1;
    im.h = hdr[0], im.w = hdr[1], im.returns = hdr[2];
    im.rgb.resize((size_t)im.h * im.w * 3);
    if (fread(im.rgb.data(), 1, im.rgb.size(), f) != im.rgb.size()) return 1;
  }
  fclose(f);
  int sigma_s = atoi(argv[2]);
  float sigma_r = atof(argv[3]);
  SpeedUpLevel level = (SpeedUpLevel)atoi(argv[4]);
  for (int run = 0, runs = atoi(argv[5]); run < runs; run++) {
    double total = 0;
    long regions = 0, returns = 0;
    std::vector<double> rates;
    for (auto& im : imgs) {
      msImageProcessor ms;
      // Outside the timed region: the RGB -> L*u*v* conversion (tessera converts colour while
      // decoding too).
      ms.DefineImage(im.rgb.data(), COLOR, im.h, im.w);
      auto t0 = std::chrono::steady_clock::now();
      ms.Filter(sigma_s, sigma_r, level);
      double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      total += s;
      returns += im.returns;
      rates.push_back(im.returns / s);
      int *labels, *counts;
      float* modes;
      regions += ms.GetRegions(&labels, &modes, &counts);
      delete[] labels;
      delete[] modes;
      delete[] counts;
    }
    std::nth_element(rates.begin(), rates.begin() + rates.size() / 2, rates.end());
    printf("edison sigma_s %d sigma_r %.1f speedup %d: %d scans, %ld returns, %.3f s, median %.2f M returns/s per scan, %ld regions\n",
           sigma_s, sigma_r, (int)level, n, returns, total, rates[rates.size() / 2] / 1e6, regions);
  }
  return 0;
}
