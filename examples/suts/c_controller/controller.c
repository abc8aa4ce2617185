/*
 * A lidarfuzz sequence system in C: a small obstacle-avoidance and speed controller that keeps
 * state across the frames of a log (protocol: docs/structural.md, "The worker protocol for logs").
 *
 * One JSON request per line on stdin:
 *   {"reset": true}                      -> clear the state, answer {"ok": true}
 *   {"points": "/path/frame.bin", ...}   -> answer {"steering": rad, "speed": m/s, "emergency_stop": bool}
 * Every request carries an "id" (the frame id and a sequence number) that its answer echoes.
 * An empty line or end of input ends it. Points are KITTI .bin (float32 x, y, z, intensity), the
 * sensor 1.73 m above a flat road.
 *
 * Code coverage: built with --coverage -DLIDARFUZZ_GCOV, the program answers a request carrying
 * "gcov_dump": true only after writing its counts (__gcov_dump, then __gcov_reset), so lidarfuzz
 * reads each step's coverage from the .gcda files (lidarfuzz.structural.gcov.GcovRecorder).
 *
 * Build: cc -O2 -o controller controller.c -lm
 * With coverage: cc --coverage -O0 -DLIDARFUZZ_GCOV -o controller controller.c -lm
 */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#ifdef LIDARFUZZ_GCOV
/* libgcov's, linked in by --coverage */
extern void __gcov_dump(void);
extern void __gcov_reset(void);
#endif

enum mode { CRUISE, SLOW, STOP };

static const float PERIOD = 0.1f, CRUISE_SPEED = 8.0f, SLOW_SPEED = 3.0f;
static const float MAX_ACCEL = 2.0f, MAX_DECEL = 3.0f, MARGIN = 2.0f;
static const float SLOW_ENTER = 15.0f, SLOW_EXIT = 20.0f, CORRIDOR = 1.5f, OBSTACLE_Z = -1.3f;
static const int RESUME_FRAMES = 3, MIN_CELL_POINTS = 5;

static enum mode state = CRUISE;
static float speed = CRUISE_SPEED, steering = 0.0f;
static int clear_frames = 0;

static void reset_state(void) {
    state = CRUISE;
    speed = CRUISE_SPEED;
    steering = 0.0f;
    clear_frames = 0;
}

static int string_field(const char *line, const char *key, char *out, size_t size) {
    const char *at = strstr(line, key);
    if (!at) return 0;
    const char *start = strchr(at + strlen(key), '"');
    if (!start) return 0;
    start++;
    const char *end = start;
    while (*end && *end != '"') end += (*end == '\\' && end[1]) ? 2 : 1; /* escapes kept as written */
    if (*end != '"' || (size_t)(end - start) >= size) return 0;
    memcpy(out, start, (size_t)(end - start));
    out[end - start] = '\0';
    return 1;
}

static int true_field(const char *line, const char *key) {
    const char *at = strstr(line, key);
    if (!at) return 0;
    at = strchr(at + strlen(key), ':');
    while (at && (*at == ':' || *at == ' ')) at++;
    return at && strncmp(at, "true", 4) == 0;
}

/* One answer line: `text` (a JSON object) with the request's "id" echoed first. */
static void answer(const char *id, const char *text, int dump) {
#ifdef LIDARFUZZ_GCOV
    if (dump) {
        __gcov_dump(); /* the step's counts are on disk before lidarfuzz reads the answer */
        __gcov_reset();
    }
#else
    (void)dump;
#endif
    printf("{\"id\": \"%s\", %s", id, text + 1);
    fflush(stdout);
}

/* The decision on one frame; nearest obstacle ahead in the corridor, and which side is freer. */
static void step(FILE *f, char *out, size_t size) {
    float p[4];
    float nearest = INFINITY;
    int left = 0, right = 0, near_points = 0;
    while (fread(p, sizeof(float), 4, f) == 4) {
        if (p[2] < OBSTACLE_Z || p[0] < 1.0f || p[0] > 40.0f) continue; /* road, behind, too far */
        if (fabsf(p[1]) < CORRIDOR) {
            near_points++;
            if (p[0] < nearest) nearest = p[0];
        } else if (p[0] < 12.0f && fabsf(p[1]) < 4.0f) {
            if (p[1] > 0) left++;
            else right++;
        }
    }
    if (near_points < MIN_CELL_POINTS) nearest = INFINITY; /* a few stray returns are no obstacle */
    float stopping = speed * speed / (2.0f * MAX_DECEL) + MARGIN;
    int emergency = 0;
    if (nearest < stopping && speed > 0.0f) {
        emergency = 1; /* EMERGENCY */
        state = STOP;
        clear_frames = 0;
    } else if (state == STOP) {
        clear_frames = nearest > SLOW_EXIT ? clear_frames + 1 : 0;
        if (clear_frames >= RESUME_FRAMES) state = nearest < SLOW_EXIT ? SLOW : CRUISE;
    } else if (state == CRUISE && nearest < SLOW_ENTER) {
        state = SLOW;
    } else if (state == SLOW && nearest > SLOW_EXIT) {
        state = CRUISE;
    }
    /* steer away from the busier side, at most 0.05 rad a step */
    float wanted = 0.0f;
    if (left > right + 20) wanted = -0.2f;
    else if (right > left + 20) wanted = 0.2f;
    if (emergency) wanted = steering;
    if (wanted > steering + 0.05f) steering += 0.05f;
    else if (wanted < steering - 0.05f) steering -= 0.05f;
    else steering = wanted;
    float target = state == STOP ? 0.0f : state == SLOW ? SLOW_SPEED : CRUISE_SPEED;
    if (emergency) speed = 0.0f;
    else if (target > speed) speed = fminf(target, speed + MAX_ACCEL * PERIOD);
    else if (target < speed) speed = fmaxf(target, speed - MAX_DECEL * PERIOD);
    snprintf(out, size, "{\"steering\": %.5f, \"speed\": %.5f, \"emergency_stop\": %s}\n", steering, speed,
             emergency ? "true" : "false");
}

int main(void) {
    char line[65536], path[4096], out[256], id[512];
    while (fgets(line, sizeof line, stdin)) {
        if (line[0] == '\n' || line[0] == '\0') break;
        int dump = true_field(line, "\"gcov_dump\"");
        if (!string_field(line, "\"id\"", id, sizeof id)) id[0] = '\0';
        if (true_field(line, "\"reset\"")) {
            reset_state();
            answer(id, "{\"ok\": true}\n", dump);
            continue;
        }
        if (!string_field(line, "\"points\"", path, sizeof path)) {
            answer(id, "{\"error\": \"request without a points path\"}\n", dump);
            continue;
        }
        FILE *f = fopen(path, "rb");
        if (!f) {
            answer(id, "{\"error\": \"cannot open points file\"}\n", dump);
            continue;
        }
        step(f, out, sizeof out);
        fclose(f);
        answer(id, out, dump);
    }
    return 0;
}
