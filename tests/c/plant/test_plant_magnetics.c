/* Flux maps: incremental inductances are the derivatives of the map, reciprocal and
 * positive definite everywhere; the inversion recovers the current from any start. */
#include <string.h>

#include "../check.h"
#include "plant_internal.h"

static void check_profile(const char *name)
{
    char path[512], err[512];
    plant_config_t cfg;
    plant_mag_t mag;
    double id, iq, worst_inv = 0.0, worst_d = 0.0;
    snprintf(path, sizeof(path), "%s/%s.toml", PROFILES_DIR, name);
    plant_config_defaults(&cfg);
    CHECK(plant_config_load(&cfg, path, err, sizeof(err)) == 0);
    CHECK(plant_mag_init(&mag, &cfg, err, sizeof(err)) == 0);

    for (id = -40.0; id <= 40.0; id += 0.73) {
        for (iq = -40.0; iq <= 40.0; iq += 0.61) {
            const double h = 1e-5;
            double psi[2], l[3], pp[2], pm[2], qp[2], qm[2], i[2];
            int it;
            plant_mag_flux(&mag, id, iq, psi, l);
            plant_mag_flux(&mag, id + h, iq, pp, NULL);
            plant_mag_flux(&mag, id - h, iq, pm, NULL);
            plant_mag_flux(&mag, id, iq + h, qp, NULL);
            plant_mag_flux(&mag, id, iq - h, qm, NULL);
            {
                const double ldd = (pp[0] - pm[0]) / (2 * h), lqd = (pp[1] - pm[1]) / (2 * h);
                const double ldq = (qp[0] - qm[0]) / (2 * h), lqq = (qp[1] - qm[1]) / (2 * h);
                const double e = fabs(ldd - l[0]) + fabs(lqq - l[1]) + fabs(ldq - l[2]) +
                                 fabs(lqd - l[2]);
                worst_d = e > worst_d ? e : worst_d;
            }
            /* positive definite: the map is invertible, the energy is bounded below */
            CHECK(l[0] > 0.0 && l[1] > 0.0 && l[0] * l[1] - l[2] * l[2] > 0.0);
            /* inversion from a cold start and from far away */
            i[0] = 0.0;
            i[1] = 0.0;
            it = plant_mag_invert(&mag, psi[0], psi[1], i, NULL);
            CHECK(it > 0 && it <= 60);
            worst_inv = fmax(worst_inv, fabs(i[0] - id) + fabs(i[1] - iq));
            i[0] = -500.0;
            i[1] = 700.0;
            it = plant_mag_invert(&mag, psi[0], psi[1], i, NULL);
            CHECK(it > 0);
            worst_inv = fmax(worst_inv, fabs(i[0] - id) + fabs(i[1] - iq));
        }
    }
    printf("%s: |Linc - numerical derivative| <= %.3g H, inversion error <= %.3g A\n", name,
           worst_d, worst_inv);
    CHECK(worst_d < 1e-8);
    CHECK(worst_inv < 1e-10);

    /* the q-axis flux is odd and strictly increasing to large currents (no fold) */
    {
        double prev = -1e9, psi[2], psi_neg[2];
        for (iq = 0.0; iq <= 200.0; iq += 0.05) {
            plant_mag_flux(&mag, 0.0, iq, psi, NULL);
            plant_mag_flux(&mag, 0.0, -iq, psi_neg, NULL);
            CHECK(psi[1] > prev);
            CHECK_NEAR(psi_neg[1], -psi[1], 1e-15);
            prev = psi[1];
        }
    }
    /* zero current: the magnet flux alone */
    {
        double psi[2];
        plant_mag_flux(&mag, 0.0, 0.0, psi, NULL);
        CHECK_NEAR(psi[0], cfg.machine.lambda_m_wb, 1e-15);
        CHECK_NEAR(psi[1], 0.0, 1e-15);
    }
}

int main(void)
{
    check_profile("ideal");
    check_profile("paper");
    check_profile("harsh");
    return check_report("test_plant_magnetics");
}
