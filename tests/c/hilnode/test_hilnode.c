/* hilnode: option values, the node options, and the counters JSON line the programs print. */
#include <stdio.h>
#include <string.h>

#include "../check.h"
#include "hilnode.h"

static const char *name(int k)
{
    static const char *const n[] = {"none", "a", "b"};
    return n[k];
}

static void test_json(void)
{
    char buf[256], small[16];
    const uint64_t counts[3] = {9, 1, 2};
    hil_json_t j;
    size_t n;
    hil_json_init(&j, buf, sizeof(buf));
    hil_json_str(&j, "program", "x");
    hil_json_u64(&j, "n", 18446744073709551615ull);
    hil_json_counts(&j, "rejects", name, counts, 1, 3);
    hil_json_fmt(&j, "us", "%.1f", 2.25);
    hil_json_open(&j, "inner");
    hil_json_member(&j, "\"faults\": {}");
    hil_json_raw(&j, "last", "null");
    n = hil_json_end(&j); /* closes "inner" too */
    CHECK(strcmp(buf, "{\"program\": \"x\", \"n\": 18446744073709551615, \"rejects\": {\"a\": 1, "
                      "\"b\": 2}, \"us\": 2.2, \"inner\": {\"faults\": {}, \"last\": null}}") == 0);
    CHECK(n == strlen(buf));
    /* a full buffer truncates and says how long the line would have been */
    hil_json_init(&j, small, sizeof(small));
    hil_json_str(&j, "program", "plant_rt");
    n = hil_json_end(&j);
    CHECK(n == strlen("{\"program\": \"plant_rt\"}") && strlen(small) == sizeof(small) - 1);
}

static void test_options(void)
{
    hil_node_opts_t o;
    uint64_t v = 7;
    CHECK(hil_parse_u64("42", 100, &v) == 0 && v == 42);
    CHECK(hil_parse_u64("101", 100, &v) != 0 && v == 42);
    CHECK(hil_parse_u64("-1", 100, &v) != 0 && hil_parse_u64("", 100, &v) != 0);
    CHECK(hil_parse_u64("4x", 100, &v) != 0 && hil_parse_u64(" 4", 100, &v) != 0);
    CHECK(hil_parse_u64(" -1", UINT64_MAX, &v) != 0 && v == 42);
    CHECK(hil_parse_u64("18446744073709551616", UINT64_MAX, &v) != 0);
    hil_node_opts_init(&o, "test");
    CHECK(o.rt_priority == 80 && o.realtime == 0 && o.max_periods == 0 && o.trace == NULL);
    CHECK(hil_node_option(&o, HIL_OPT_REALTIME, NULL) == 1 && o.realtime == 1);
    CHECK(hil_node_option(&o, HIL_OPT_MAX_PERIODS, "12") == 1 && o.max_periods == 12);
    CHECK(hil_node_option(&o, HIL_OPT_RT_PRIORITY, "100") == -1 && o.rt_priority == 80);
    CHECK(hil_node_option(&o, HIL_OPT_CHANNEL, "c1") == 1 && strcmp(o.channel, "c1") == 0);
    CHECK(hil_node_option(&o, HIL_OPT_NODE_END, "x") == 0);
}

int main(void)
{
    test_json();
    test_options();
    return check_report("test_hilnode");
}
