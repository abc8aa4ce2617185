/*
 * A lidarfuzz worker-mode system under test in C (protocol: docs/suts.md).
 *
 * Reads one JSON request per line on stdin, takes the "points" path (KITTI .bin:
 * float32 x, y, z, intensity), and answers one JSON line: one "Car" box around the
 * above-ground points in the 20 m x 8 m corridor ahead, when there are enough of them.
 * An empty line or end of input ends it. Build: cc -O2 -o detector detector.c
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

static int points_path(const char *line, char *out, size_t size) {
    const char *key = strstr(line, "\"points\"");
    if (!key) return 0;
    const char *start = strchr(key + 8, '"');
    if (!start) return 0;
    start++;
    const char *end = strchr(start, '"');
    if (!end || (size_t)(end - start) >= size) return 0;
    memcpy(out, start, (size_t)(end - start));
    out[end - start] = '\0';
    return 1;
}

int main(void) {
    char line[8192];
    char path[4096];
    while (fgets(line, sizeof line, stdin)) {
        if (line[0] == '\n' || line[0] == '\0') break;
        if (!points_path(line, path, sizeof path)) {
            printf("{\"error\": \"request without a points path\"}\n");
            fflush(stdout);
            continue;
        }
        FILE *f = fopen(path, "rb");
        if (!f) {
            printf("{\"error\": \"cannot open points file\"}\n");
            fflush(stdout);
            continue;
        }
        float p[4];
        long n = 0;
        float lo[3] = {1e9f, 1e9f, 1e9f}, hi[3] = {-1e9f, -1e9f, -1e9f};
        while (fread(p, sizeof(float), 4, f) == 4) {
            if (p[0] < 2.0f || p[0] > 22.0f || p[1] < -4.0f || p[1] > 4.0f || p[2] < -1.3f) continue;
            for (int k = 0; k < 3; k++) {
                if (p[k] < lo[k]) lo[k] = p[k];
                if (p[k] > hi[k]) hi[k] = p[k];
            }
            n++;
        }
        fclose(f);
        if (n < 20) {
            printf("{\"detections\": []}\n");
        } else {
            printf("{\"detections\": [{\"label\": \"Car\", \"box\": [%.4f, %.4f, %.4f, %.4f, %.4f, %.4f, 0.0], "
                   "\"score\": %.3f}]}\n",
                   (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2, hi[0] - lo[0] + 0.1,
                   hi[1] - lo[1] + 0.1, hi[2] - lo[2] + 0.1, n > 500 ? 1.0 : n / 500.0);
        }
        fflush(stdout);
    }
    return 0;
}
