/* Configuration: the three profiles load, bad files and overrides are refused with a
 * message naming file, line and field. */
#include <stdio.h>
#include <string.h>

#include "../check.h"
#include "plant_core.h"

static int load_text(const char *text, plant_config_t *cfg, char *err, size_t errlen)
{
    static int serial = 0;
    char path[256];
    FILE *f;
    snprintf(path, sizeof(path), "/tmp/plant_cfg_test_%d_%d.toml", (int)sizeof(cfg), serial++);
    f = fopen(path, "w");
    if (!f) {
        return -2;
    }
    fputs(text, f);
    fclose(f);
    plant_config_defaults(cfg);
    {
        const int r = plant_config_load(cfg, path, err, errlen);
        remove(path);
        return r;
    }
}

static int contains(const char *s, const char *part)
{
    return strstr(s, part) != NULL;
}

int main(void)
{
    plant_config_t cfg;
    char err[512];
    const char *names[3] = {"ideal", "paper", "harsh"};
    int k;

    for (k = 0; k < 3; ++k) {
        char path[512];
        snprintf(path, sizeof(path), "%s/%s.toml", PROFILES_DIR, names[k]);
        plant_config_defaults(&cfg);
        CHECK(plant_config_load(&cfg, path, err, sizeof(err)) == 0);
        if (plant_config_load(&cfg, path, err, sizeof(err)) != 0) {
            fprintf(stderr, "%s\n", err);
        }
    }
    /* spot values of the profiles against docs/design.md section 5 */
    plant_config_defaults(&cfg);
    CHECK(plant_config_load(&cfg, PROFILES_DIR "/harsh.toml", err, sizeof(err)) == 0);
    CHECK_NEAR(cfg.machine.rs_ohm, 1.93 * 1.3, 1e-12);
    CHECK_NEAR(cfg.machine.lambda_m_wb, 0.216 * 0.95, 1e-12);
    CHECK(cfg.adc.bits == 12 && cfg.inverter.dead_time_s == 3e-6);
    CHECK_NEAR(cfg.sensors.noise_rms_a, 0.005, 0);

    CHECK(load_text("[machine]\nrs_ohm = 2.0\n\n# comment\n[adc]\nbits = 16 # trailing\n", &cfg, err,
                    sizeof(err)) == 0);
    CHECK(cfg.machine.rs_ohm == 2.0 && cfg.adc.bits == 16);
    CHECK(load_text("[inverter]\ndead_time_s = 1_0e-7\n", &cfg, err, sizeof(err)) == 0 &&
          cfg.inverter.dead_time_s == 1e-6);
    CHECK(load_text("[inverter]\nvdc_v = 2_000\n", &cfg, err, sizeof(err)) == 0 &&
          cfg.inverter.vdc_v == 2000.0);

    CHECK(load_text("[machine]\nrs_ohm = 1.0\nbogus = 3\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":3:") && contains(err, "machine.bogus"));
    CHECK(load_text("[machine]\n\nrs_ohm = fast\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":3:") && contains(err, "machine.rs_ohm") && contains(err, "not a number"));
    CHECK(load_text("[adc]\nbits = 25\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":2:") && contains(err, "adc.bits"));
    CHECK(load_text("[adc]\nbits = 12.5\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, "adc.bits") && contains(err, "integer"));
    CHECK(load_text("[adc]\nbits = 12\nbits = 14\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":3:") && contains(err, "twice"));
    CHECK(load_text("[motor]\nrs_ohm = 1\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":1:") && contains(err, "motor"));
    CHECK(load_text("rs_ohm = 1\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":1:") && contains(err, "outside any"));
    CHECK(load_text("[machine\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":1:"));
    CHECK(load_text("[shaft]\nj_kgm2 = 0\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, "shaft.j_kgm2"));
    CHECK(load_text("[sensors]\nnoise_rms_a = nan\n", &cfg, err, sizeof(err)) != 0);
    CHECK(load_text("[sensors]\nnoise_rms_a = inf\n", &cfg, err, sizeof(err)) != 0);
    CHECK(load_text("[sensors]\nnoise_rms_a = .5\n", &cfg, err, sizeof(err)) != 0);
    CHECK(load_text("[sensors]\nnoise_rms_a\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, ":2:"));
    /* cross-field checks name the field */
    CHECK(load_text("[inverter]\ndead_time_s = 2.005e-6\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, "inverter.dead_time_s") && contains(err, "ticks"));
    CHECK(load_text("[magnetics]\nldq_ref_h = -0.05\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, "magnetics.ldq_ref_h"));
    CHECK(load_text("[magnetics]\nld_sat_h = 0.02\n", &cfg, err, sizeof(err)) != 0);
    CHECK(contains(err, "magnetics.ld_sat_h"));
    CHECK(load_text("[magnetics]\nlq_sat_per_a2 = 0.015873\nlq_ext_from_a = 7.9\n", &cfg, err,
                    sizeof(err)) != 0);
    CHECK(contains(err, "magnetics.lq_ext_from_a"));
    plant_config_defaults(&cfg);
    CHECK(plant_config_load(&cfg, "/nonexistent/x.toml", err, sizeof(err)) != 0);
    CHECK(contains(err, "/nonexistent/x.toml"));

    /* --set */
    plant_config_defaults(&cfg);
    CHECK(plant_config_set(&cfg, "sensors.noise_rms_a=0.002", err, sizeof(err)) == 0);
    CHECK(cfg.sensors.noise_rms_a == 0.002);
    CHECK(plant_config_set(&cfg, " load.mode = 1 ", err, sizeof(err)) == 0 && cfg.load.mode == 1);
    CHECK(plant_config_set(&cfg, "load.mode=3", err, sizeof(err)) != 0);
    CHECK(contains(err, "load.mode"));
    CHECK(plant_config_set(&cfg, "load.modes=1", err, sizeof(err)) != 0);
    CHECK(contains(err, "unknown field"));
    CHECK(plant_config_set(&cfg, "loadmode=1", err, sizeof(err)) != 0);
    CHECK(plant_config_set(&cfg, "load.mode", err, sizeof(err)) != 0);
    CHECK(plant_config_set(&cfg, "adc.bits=", err, sizeof(err)) != 0);
    {
        /* a value of 400 digits: the message shows it shortened, so the reason after it is
         * not cut off by a message buffer (the rig's is 512 bytes, as here) */
        char assign[480];
        const char *tail;
        memcpy(assign, "sensors.noise_rms_a=", 20);
        memset(assign + 20, '9', 400);
        assign[420] = '\0';
        CHECK(plant_config_set(&cfg, assign, err, sizeof(err)) != 0);
        CHECK(strlen(err) < 200 && contains(err, "sensors.noise_rms_a") && contains(err, "..."));
        tail = strrchr(err, ':');
        CHECK(tail != NULL && strlen(tail) > 3); /* the reason comes last and whole */
        if (tail != NULL) {
            printf("400-digit value: %s\n", err);
        }
    }
    CHECK(plant_config_key_count() > 40);
    for (k = 0; k < plant_config_key_count(); ++k) {
        char assign[128];
        CHECK(plant_config_key_name(k) != NULL);
        /* every listed key is accepted by --set (value checked against its own range) */
        snprintf(assign, sizeof(assign), "%s=abc", plant_config_key_name(k));
        CHECK(plant_config_set(&cfg, assign, err, sizeof(err)) != 0 && contains(err, "not a number"));
    }
    return check_report("test_plant_config");
}
