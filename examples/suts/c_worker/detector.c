/*
 * A lidarfuzz worker-mode system under test in C (protocol: docs/suts.md).
 *
 * Reads one JSON request per line on stdin, takes the "points" path (KITTI .bin:
 * float32 x, y, z, intensity), and answers one JSON line: one "Car" box around the
 * above-ground points in the 20 m x 8 m corridor ahead, when there are enough of them.
 * Every answer echoes the request's "id" (the frame id and a sequence number), which keeps
 * answers and frames paired. An empty line or end of input ends it.
 * Build: cc -O2 -o detector detector.c
 */
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

/* The raw text of the JSON string field `key` ("" when absent; escapes kept, to be written back as is). */
static int string_field(const char *line, const char *key, char *out, size_t size) {
    out[0] = '\0';
    const char *at = strstr(line, key);
    if (!at) return 0;
    const char *start = strchr(at + strlen(key), '"');
    if (!start) return 0;
    start++;
    const char *end = start;
    while (*end && *end != '"') end += (*end == '\\' && end[1]) ? 2 : 1;
    if (*end != '"' || (size_t)(end - start) >= size) return 0;
    memcpy(out, start, (size_t)(end - start));
    out[end - start] = '\0';
    return 1;
}

int main(void) {
    char line[8192];
    char path[4096], id[512];
    while (fgets(line, sizeof line, stdin)) {
        if (line[0] == '\n' || line[0] == '\0') break;
        string_field(line, "\"id\"", id, sizeof id);
        if (!string_field(line, "\"points\"", path, sizeof path)) {
            printf("{\"id\": \"%s\", \"error\": \"request without a points path\"}\n", id);
            fflush(stdout);
            continue;
        }
        FILE *f = fopen(path, "rb");
        if (!f) {
            printf("{\"id\": \"%s\", \"error\": \"cannot open points file\"}\n", id);
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
            printf("{\"id\": \"%s\", \"detections\": []}\n", id);
        } else {
            printf("{\"id\": \"%s\", \"detections\": [{\"label\": \"Car\", \"box\": [%.4f, %.4f, %.4f, %.4f, "
                   "%.4f, %.4f, 0.0], \"score\": %.3f}]}\n", id,
                   (lo[0] + hi[0]) / 2, (lo[1] + hi[1]) / 2, (lo[2] + hi[2]) / 2, hi[0] - lo[0] + 0.1,
                   hi[1] - lo[1] + 0.1, hi[2] - lo[2] + 0.1, n > 500 ? 1.0 : n / 500.0);
        }
        fflush(stdout);
    }
    return 0;
}
