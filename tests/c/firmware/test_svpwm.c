/* SVPWM pattern, stretching/compensation and sampling plan, checked from the compare values
 * alone with the semantics of docs/interfaces.md (upper gate on during [cmp_up, 2*TBPRD -
 * cmp_dn)). Volt-seconds of a pattern follow from the per-phase on-times (isolated neutral:
 * the common mode drops out). */
#include <string.h>

#include "fw_internal.h"
#include "fw_test.h"

#define P 10000
#define VDC 200.0
#define TICK 1e-8

static int phase_on(const fw_plan_t *pl, int x, int t)
{
    int on = pl->cmp_up[x];
    int off = 2 * (int)FW_TBPRD - pl->cmp_dn[x];
    return t >= on && t < off;
}

static int state_at(const fw_plan_t *pl, int t)
{
    return phase_on(pl, 0, t) | (phase_on(pl, 1, t) << 1) | (phase_on(pl, 2, t) << 2);
}

/* applied volt-seconds of the pattern (V*s), from the compare values */
static void applied_vs(const fw_plan_t *pl, double vdc, double *va, double *vb)
{
    double tau[3];
    int x;
    for (x = 0; x < 3; x++) {
        int on = pl->cmp_up[x];
        int off = 2 * (int)FW_TBPRD - pl->cmp_dn[x];
        tau[x] = (off > on) ? (double)(off - on) * TICK : 0.0;
    }
    *va = vdc * (2.0 / 3.0) * (tau[0] - 0.5 * (tau[1] + tau[2]));
    *vb = vdc / sqrt(3.0) * (tau[1] - tau[2]);
}

static const int vec_bits[7] = {0, 1, 3, 2, 6, 4, 5};

/* every measured window is one whole switching state of >= tmin with its SOCs inside */
static void check_windows(const fw_plan_t *pl, const fw_pwm_cfg_t *cfg, const char *what)
{
    int w;
    int total = 0;
    for (w = 0; w < 3; w++) {
        const fw_window_t *win = &pl->win[w];
        int bits;
        int t;
        int k;
        if (!win->measured) {
            continue;
        }
        bits = (win->vec == 7) ? 7 : vec_bits[win->vec];
        CHECK(win->end > win->start && (int)win->end - (int)win->start >= cfg->tmin,
              "%s: window %d [%u,%u) shorter than tmin", what, w, win->start, win->end);
        for (t = win->start; t < win->end; t++) {
            if (state_at(pl, t) != bits) {
                CHECK(0, "%s: window %d state %d at tick %d, expected %d", what, w,
                      state_at(pl, t), t, bits);
                break;
            }
        }
        if (win->start > 0) {
            CHECK(state_at(pl, win->start - 1) != bits, "%s: window %d does not start at an edge",
                  what, w);
        }
        if (win->end < P) {
            CHECK(state_at(pl, win->end) != bits, "%s: window %d does not end at an edge", what, w);
        }
        CHECK(win->soc_count == cfg->n_per_state, "%s: window %d has %d socs", what, w,
              win->soc_count);
        for (k = 0; k < win->soc_count; k++) {
            int s = pl->soc[win->soc_first + k];
            CHECK(s >= win->start + cfg->soc_on && s <= win->end - cfg->soc_off && s <= P - 1,
                  "%s: soc %d at %d outside [%d, %d]", what, k, s, win->start + cfg->soc_on,
                  win->end - cfg->soc_off);
        }
        total += win->soc_count;
    }
    CHECK(total == pl->n_soc && pl->n_soc <= FW_MAX_SOC, "%s: n_soc %d vs %d", what, pl->n_soc,
          total);
    for (w = 0; w < 3; w++) {
        CHECK(pl->cmp_up[w] <= FW_TBPRD && pl->cmp_dn[w] <= FW_TBPRD, "%s: compare out of range",
              what);
    }
}

static fw_pwm_cfg_t make_cfg(double tmin_us, double on_us, double off_us, int n, int stretch)
{
    fw_pwm_cfg_t cfg;
    memset(&cfg, 0, sizeof cfg);
    cfg.tmin = (uint16_t)(tmin_us * 100.0 + 0.5);
    cfg.soc_on = (uint16_t)(on_us * 100.0 + 0.5);
    cfg.soc_off = (uint16_t)(off_us * 100.0 + 0.5);
    cfg.n_per_state = (int16_t)n;
    cfg.stretch = (int16_t)stretch;
    return cfg;
}

/* Sweep all sectors and magnitudes up to the modulation limit on the tick lattice, where the
 * pattern must reproduce the reference exactly (1e-9 V*s). */
static void lattice_sweep(const fw_pwm_cfg_t *cfg, const char *name)
{
    const double kv = 2.0 * VDC / 3.0;
    int sector;
    int n1;
    int n2;
    int both_measured = 0;
    int periods = 0;
    for (sector = 1; sector <= 6; sector++) {
        double phi1 = (sector - 1) * M_PI / 3.0;
        double phi2 = sector * M_PI / 3.0;
        for (n1 = 0; n1 <= P - cfg->tmin; n1 += 137) {
            for (n2 = 0; n1 + n2 <= P - cfg->tmin; n2 += 173) {
                fw_plan_t pl;
                double ra = kv * (n1 * cos(phi1) + n2 * cos(phi2)) * TICK;
                double rb = kv * (n1 * sin(phi1) + n2 * sin(phi2)) * TICK;
                double va;
                double vb;
                char what[96];
                fw_svpwm_plan(cfg, (real_t)VDC, fw_c((real_t)(ra / 1e-4), (real_t)(rb / 1e-4)),
                              NULL, (uint32_t)periods, &pl);
                applied_vs(&pl, VDC, &va, &vb);
                snprintf(what, sizeof what, "%s s%d n1=%d n2=%d", name, sector, n1, n2);
                CHECK(fabs(va - ra) <= 1e-9 && fabs(vb - rb) <= 1e-9,
                      "%s: volt-seconds (%.3e, %.3e) vs reference (%.3e, %.3e)", what, va, vb, ra,
                      rb);
                CHECK(!pl.clipped, "%s: clipped inside the modulation limit", what);
                CHECK(pl.win[FW_WIN_ZERO].measured, "%s: zero state not measured", what);
                check_windows(&pl, cfg, what);
                if (cfg->stretch && cfg->tmin <= 2000) {
                    /* 5*Tmin <= Ts: at least one active state is always measured */
                    CHECK(pl.win[FW_WIN_ODD].measured || pl.win[FW_WIN_EVEN].measured,
                          "%s: no active state measured", what);
                }
                if (n1 >= cfg->tmin && n2 >= cfg->tmin) {
                    CHECK(pl.win[FW_WIN_ODD].measured && pl.win[FW_WIN_EVEN].measured,
                          "%s: long vectors not both measured", what);
                }
                both_measured += pl.win[FW_WIN_ODD].measured && pl.win[FW_WIN_EVEN].measured;
                periods++;
            }
        }
    }
    printf("%s: %d lattice periods, both actives measured in %d\n", name, periods, both_measured);
}

/* Off-lattice references: per-period error within one tick of each vector, and the carried
 * rounding error keeps the running sum bounded (no drift). */
static void carry_sequence(const fw_pwm_cfg_t *cfg)
{
    const double kv = 2.0 * VDC / 3.0;
    const double vmax = fw_svpwm_vmax((real_t)VDC, cfg->tmin);
    fw_mod_t carry = {{0.0f, 0.0f}, 0};
    double sum_a = 0.0;
    double sum_b = 0.0;
    double worst = 0.0;
    int k;
    for (k = 0; k < 20000; k++) {
        fw_plan_t pl;
        double mag = vmax * (0.999 * fabs(sin(k * 0.0013)));
        double ang = k * 0.0417;
        float ra = (float)(mag * cos(ang));
        float rb = (float)(mag * sin(ang));
        double va;
        double vb;
        fw_svpwm_plan(cfg, (real_t)VDC, fw_c(ra, rb), &carry, (uint32_t)k, &pl);
        applied_vs(&pl, VDC, &va, &vb);
        CHECK(fabs(va - ra * 1e-4) <= 2.0 * kv * TICK && fabs(vb - rb * 1e-4) <= 2.0 * kv * TICK,
              "period %d: error beyond the rounding bound", k);
        /* the plan reports exactly what its compares apply */
        CHECK(fabs(pl.v_applied.re * 1e-4 - va) <= 1e-9 + 1e-6 * fabs(va) &&
                  fabs(pl.v_applied.im * 1e-4 - vb) <= 1e-9 + 1e-6 * fabs(vb),
              "period %d: v_applied disagrees with the compares", k);
        sum_a += va - ra * 1e-4;
        sum_b += vb - rb * 1e-4;
        worst = fmax(worst, hypot(sum_a, sum_b));
        check_windows(&pl, cfg, "carry");
    }
    printf("carry: worst accumulated volt-second error %.3e V*s (1 tick*kv = %.3e)\n", worst,
           kv * TICK);
    CHECK(worst <= 1.5 * kv * TICK, "accumulated error %.3e drifts", worst);
}

static void limit_checks(const fw_pwm_cfg_t *cfg)
{
    double vmax = fw_svpwm_vmax((real_t)VDC, cfg->tmin);
    int k;
    CHECK(fabs(vmax - (1.0 - 0.2) * VDC / sqrt(3.0)) < 1e-3, "vmax %.4f", vmax);
    for (k = 0; k < 360; k++) {
        fw_plan_t pl;
        double ang = k * M_PI / 180.0;
        fw_svpwm_plan(cfg, (real_t)VDC,
                      fw_c((real_t)(0.9999 * vmax * cos(ang)), (real_t)(0.9999 * vmax * sin(ang))),
                      NULL, 0, &pl);
        CHECK(!pl.clipped, "clipped inside the circle at %d deg", k);
        CHECK(pl.win[FW_WIN_ZERO].measured, "no zero window at the limit, %d deg", k);
        fw_svpwm_plan(cfg, (real_t)VDC,
                      fw_c((real_t)(1.2 * VDC / sqrt(3.0) * cos(ang)),
                           (real_t)(1.2 * VDC / sqrt(3.0) * sin(ang))),
                      NULL, 0, &pl);
        CHECK(pl.clipped, "not clipped outside the hexagon at %d deg", k);
        check_windows(&pl, cfg, "clipped");
    }
}

/* standstill: zero reference, all five states of Tmin, zero volt-seconds */
static void zero_vector(const fw_pwm_cfg_t *cfg)
{
    fw_plan_t pl;
    double va;
    double vb;
    fw_svpwm_plan(cfg, (real_t)VDC, fw_c(0.0f, 0.0f), NULL, 0, &pl);
    applied_vs(&pl, VDC, &va, &vb);
    CHECK(fabs(va) < 1e-12 && fabs(vb) < 1e-12, "zero reference applies %.3e %.3e", va, vb);
    CHECK(pl.win[0].measured && pl.win[1].measured && pl.win[2].measured,
          "standstill pattern does not measure all three states");
    CHECK(pl.layout == FW_LAYOUT_STRETCH && pl.c_odd == cfg->tmin && pl.c_even == cfg->tmin,
          "standstill compensation %d %d", (int)pl.c_odd, (int)pl.c_even);
    check_windows(&pl, cfg, "zero");
}

/* FULL modulation (whole voltage range): inside the hexagon Vdc/sqrt3 the pattern reproduces
 * the reference exactly (no Tmin reserve); beyond it the applied vector is the nearest point of
 * the hexagon (analytic: the edge point along the normal, or the vertex); without a measured
 * zero window every state long enough gets current samples clear of its edges. */
static void full_range(void)
{
    fw_pwm_cfg_t cfg = make_cfg(20.0, 8.0, 1.0, 5, 1);
    const double lin = VDC / sqrt(3.0);
    const double vtx = 2.0 * VDC / 3.0;
    int k;
    cfg.full_range = 1;
    for (k = 0; k < 720; k++) {
        double ang = (k + 0.25) * M_PI / 360.0;
        double mags[4] = {0.5 * lin, 0.999 * lin, 1.08 * lin, 3.0 * lin};
        int j;
        for (j = 0; j < 4; j++) {
            fw_plan_t pl;
            fw_mod_t carry = {{0.0f, 0.0f}, 0};
            double va, vb, ea, eb;
            double ra = mags[j] * cos(ang), rb = mags[j] * sin(ang);
            int s;
            fw_svpwm_plan(&cfg, (real_t)VDC, fw_c((real_t)ra, (real_t)rb), &carry, 0u, &pl);
            applied_vs(&pl, VDC, &va, &vb);
            va /= 1e-4;
            vb /= 1e-4;
            double sec = floor(ang / (M_PI / 3.0));
            double mid = (sec + 0.5) * M_PI / 3.0;
            /* the sector's edge is the line at distance lin along its middle direction */
            int inside = ra * cos(mid) + rb * sin(mid) <= lin;
            if (inside) {
                ea = ra;
                eb = rb;
            } else {
                /* nearest point of the hexagon: the foot on the edge, or its vertex */
                double along = -ra * sin(mid) + rb * cos(mid); /* component along the edge */
                double half = vtx * 0.5;                       /* half the edge length */
                if (along > half) {
                    along = half;
                } else if (along < -half) {
                    along = -half;
                }
                ea = lin * cos(mid) - along * sin(mid);
                eb = lin * sin(mid) + along * cos(mid);
            }
            CHECK(fabs(va - ea) < 0.03 && fabs(vb - eb) < 0.03,
                  "full range %.3f x lin at %.2f deg: applied (%.3f, %.3f) V, expected (%.3f, "
                  "%.3f)", mags[j] / lin, ang * 180.0 / M_PI, va, vb, ea, eb);
            CHECK(pl.clipped == !inside, "clipped flag at %.3f x lin", mags[j] / lin);
            if (!pl.win[FW_WIN_ZERO].measured) {
                CHECK(pl.n_soc > pl.n_soc_windows, "current samples without a zero window");
            }
            for (s = 0; s < pl.n_soc; s++) {
                int t = pl.soc[s];
                int st = state_at(&pl, t);
                CHECK(st == state_at(&pl, t - cfg.soc_on) && st == state_at(&pl, t + cfg.soc_off - 1),
                      "sample %d at %d ticks within soc_on/soc_off of an edge", s, t);
            }
        }
    }
}

/* The overmodulation table: the fundamental of the minimum-distance projection starts at the
 * linear limit, grows monotonically and approaches six-step (2 sqrt3 / pi of Vdc/sqrt3); the
 * inverse hits the table's own points. */
static void overmodulation_table(void)
{
    real_t ref[FW_OM_N], fund[FW_OM_N];
    int k;
    fw_svpwm_om_init(ref, fund);
    CHECK(fabs(fund[0] - 1.0) < 1e-6, "fundamental at the linear limit %.6f", (double)fund[0]);
    for (k = 1; k < FW_OM_N; k++) {
        CHECK(fund[k] > fund[k - 1], "monotonic at %d", k);
    }
    CHECK(fabs(fund[FW_OM_N - 1] - 2.0 * sqrt(3.0) / M_PI) < 0.005 * 2.0 * sqrt(3.0) / M_PI,
          "towards six-step: %.5f vs %.5f", (double)fund[FW_OM_N - 1], 2.0 * sqrt(3.0) / M_PI);
    for (k = 0; k < FW_OM_N; k++) {
        double r = fw_svpwm_om_ref(ref, fund, fund[k]);
        CHECK(fabs(r - ref[k]) < 1e-4 * ref[k], "inverse at %d: %.5f vs %.5f", k, r,
              (double)ref[k]);
    }
    CHECK(fabs(fw_svpwm_om_ref(ref, fund, 0.7f) - 0.7) < 1e-6, "linear range unchanged");
}

int main(void)
{
    full_range();
    overmodulation_table();
    fw_pwm_cfg_t paper = make_cfg(20.0, 10.0, 5.0, 2, 1);
    fw_pwm_cfg_t multi = make_cfg(20.0, 8.0, 4.0, 5, 1);
    fw_pwm_cfg_t long_tmin = make_cfg(24.0, 10.0, 5.0, 3, 1); /* 5*Tmin > Ts */
    fw_pwm_cfg_t no_stretch = make_cfg(20.0, 10.0, 5.0, 2, 0);
    lattice_sweep(&paper, "paper");
    lattice_sweep(&multi, "5 samples");
    lattice_sweep(&long_tmin, "tmin 24us");
    lattice_sweep(&no_stretch, "no stretch");
    carry_sequence(&paper);
    limit_checks(&paper);
    zero_vector(&paper);
    TEST_DONE();
}
