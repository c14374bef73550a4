// The single-pass range-image segmentation the 5 M points/s target comes from
// (Bogoslavskyi & Stachniss, IROS 2016), written here from the paper's description to time it
// on the same scans: one breadth-first labelling over the range image, where two neighbouring
// returns join when the angle beta = atan2(d2 sin a, d1 - d2 cos a) between the beam of the
// nearer one and the line through both exceeds THETA (d1 >= d2 their ranges, a the angle between
// the beams: 2 pi / width along a ring, the rings' elevation difference across rings). No
// ground removal (the paper runs one before this; it is left out, so this is a lower bound of
// the method's cost).
// Usage: single_pass RANGE.raw THETA_DEG RUNS
// Prints per run: total seconds, median returns/s per scan, segments of >= 10 returns.
#include <algorithm>
#include <chrono>
#include <cmath>
#include <cstdio>
#include <cstdlib>
#include <vector>

struct Image {
  int h, w, returns;
  std::vector<float> elev, range;
};

int main(int argc, char** argv) {
  if (argc != 4) {
    fprintf(stderr, "usage: single_pass RANGE.raw THETA_DEG RUNS\n");
    return 2;
  }
  FILE* f = fopen(argv[1], "rb");
  int n = 0;
  if (!f || fread(&n, 4, 1, f) != 1) {
    fprintf(stderr, "single_pass: cannot read %s\n", argv[1]);
    return 1;
  }
  std::vector<Image> imgs(n);
  for (auto& im : imgs) {
    int hdr[3];
    if (fread(hdr, 4, 3, f) != 3) return 1;
    im.h = hdr[0], im.w = hdr[1], im.returns = hdr[2];
    im.elev.resize(im.h);
    im.range.resize((size_t)im.h * im.w);
    if (fread(im.elev.data(), 4, im.h, f) != (size_t)im.h) return 1;
    if (fread(im.range.data(), 4, im.range.size(), f) != im.range.size()) return 1;
  }
  fclose(f);
  const double theta = atof(argv[2]) * M_PI / 180.0;
  const float st = (float)std::sin(theta), ct = (float)std::cos(theta);
  std::vector<unsigned> label;
  std::vector<int> queue;
  for (int run = 0, runs = atoi(argv[3]); run < runs; run++) {
    double total = 0;
    long returns = 0, segments = 0;
    std::vector<double> rates;
    for (const auto& im : imgs) {
      const int h = im.h, w = im.w;
      // Per sensor, not per scan in a real system; outside the timed region.
      const float ah = (float)(2 * M_PI / w);
      const float sh = std::sin(ah), chh = std::cos(ah);
      std::vector<float> sv(h, 0), cv(h, 1);  // row r to row r + 1
      for (int r = 0; r + 1 < h; r++) {
        float a = std::fabs(im.elev[r + 1] - im.elev[r]);
        sv[r] = std::sin(a), cv[r] = std::cos(a);
      }
      auto t0 = std::chrono::steady_clock::now();
      const float* R = im.range.data();
      label.assign((size_t)h * w, 0);
      queue.resize((size_t)h * w);
      unsigned next = 0;
      // beta > theta  <=>  sin(beta - theta) > 0, beta in (0, pi): no atan2 needed.
      auto joins = [&](float ra, float rb, float s, float c) {
        float d1 = std::max(ra, rb), d2 = std::min(ra, rb);
        return d2 * s * ct - (d1 - d2 * c) * st > 0;
      };
      for (int p = 0; p < h * w; p++) {
        if (R[p] <= 0 || label[p]) continue;
        unsigned l = ++next;
        int head = 0, tail = 0, size = 0;
        label[p] = l;
        queue[tail++] = p;
        while (head < tail) {
          int q = queue[head++];
          size++;
          int r = q / w, c = q - r * w;
          float rq = R[q];
          int nb[4] = {r > 0 ? q - w : -1, r + 1 < h ? q + w : -1, r * w + (c + w - 1) % w,
                       r * w + (c + 1) % w};
          for (int k = 0; k < 4; k++) {
            int m = nb[k];
            if (m < 0 || R[m] <= 0 || label[m]) continue;
            bool ok = k == 0   ? joins(rq, R[m], sv[r - 1], cv[r - 1])
                      : k == 1 ? joins(rq, R[m], sv[r], cv[r])
                               : joins(rq, R[m], sh, chh);
            if (ok) {
              label[m] = l;
              queue[tail++] = m;
            }
          }
        }
        segments += size >= 10;
      }
      double s = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
      total += s;
      returns += im.returns;
      rates.push_back(im.returns / s);
    }
    std::nth_element(rates.begin(), rates.begin() + rates.size() / 2, rates.end());
    printf("single-pass theta %.1f deg: %d scans, %ld returns, %.3f s, median %.2f M returns/s per scan, %ld segments of >= 10 returns\n",
           theta * 180 / M_PI, n, returns, total, rates[rates.size() / 2] / 1e6, segments);
  }
  return 0;
}
