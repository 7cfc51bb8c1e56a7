%% Common Test suite of docs/ha.md section 4, "Three machines", as written:
%% scripts/test-three-machines.sh makes the laptop, the desktop and the
%% tablet out of network namespaces (each with its own /etc/hosts naming
%% the three, its own /etc/evatar, /opt/evatar and /var/lib/evatar), takes
%% the tarball of evatar_test_release:tarball/0 (EVATAR_TAR, or `rebar3 as
%% prod tar' once for the run), and follows the
%% section's steps: certificates and cookie on the laptop, copied and
%% installed on each, /etc/evatar/env with `EVATAR_NODE=evatar@laptop', TLS
%% distribution and the TLS listener, each node started as the systemd
%% unit starts it; every node must answer `bin/evatar ping' run the
%% section's way, and `bin/evatar cluster' on the laptop must show the
%% three up with a quorum, connected over TLS. Skipped, saying why, when
%% network namespaces cannot be made (not root, no `ip').
-module(three_machines_SUITE).

-include_lib("common_test/include/ct.hrl").
-include_lib("stdlib/include/assert.hrl").

-export([suite/0, all/0, init_per_suite/1, end_per_suite/1]).
-export([section_4_as_written/1]).

suite() -> [{timetrap, {minutes, 15}}].

all() -> [section_4_as_written].

init_per_suite(Config) ->
    case evatar_test_net_netns:available() of
        ok -> Config;
        {skip, Why} -> {skip, Why}
    end.

end_per_suite(_Config) ->
    ok.

%% The section's recipe, on three machines; the script's output is in the
%% case's log.
section_4_as_written(Config) ->
    Root = evatar_test_cluster:repo_root(),
    Script = filename:join([Root, "scripts", "test-three-machines.sh"]),
    Work = filename:join(?config(priv_dir, Config), "machines"),
    Tar = evatar_test_release:tarball(),
    Port = open_port({spawn_executable, "/bin/bash"},
                     [{args, [Script, Work, Tar]}, exit_status, stderr_to_stdout, binary]),
    {Status, Out} = collect(Port, []),
    ct:pal("scripts/test-three-machines.sh: exit ~p~n~ts", [Status, Out]),
    case Status of
        77 -> {skip, string:trim(Out)};
        _ ->
            ?assertEqual(0, Status, Out),
            ?assertMatch({match, _}, re:run(Out, "^PASSED", [multiline]), Out)
    end.

collect(Port, Acc) ->
    receive
        {Port, {data, D}} -> collect(Port, [D | Acc]);
        {Port, {exit_status, S}} -> {S, binary_to_list(iolist_to_binary(lists:reverse(Acc)))}
    after evatar_test_time:ms(840000) ->
            ct:fail({script_hangs, lists:reverse(Acc)})
    end.
