%% -*- erlang -*-
%% A test node driven by commands on stdin, for the tests of clients in other
%% languages (clients/python, clients/java) that need more than
%% scripts/test-node.sh: port connectors and avatar_sim's smart home on a
%% simulated clock. Run it through scripts/test-node-ctl.sh (which sets the
%% code path). It listens on 127.0.0.1 (EVATAR_PORT or a free port),
%% creates the pairings named on the command line, prints
%%   EVATAR_PORT=<port>
%% and then answers each command line with one or more lines, the last
%% starting with OK or ERROR. It halts when stdin closes.
%%
%% Arguments: PAIRING:AGENT_CREDENTIAL:AVATAR_CREDENTIAL[:FEEDBACK_TIMEOUT_MS]...
%%            [--home PAIRING:AVATAR_CREDENTIAL:SPOOL_DIR]
%% --home starts the easy smart home (one gateway with every device) joined
%% to PAIRING, on a clock at 17:55 on 2024-11-15 running at speed 2, with the
%% holiday evening's script (an intruder at 21:40), as
%% reference_agents_holiday does.
%%
%% Commands:
%%   port NAME PROGRAM [ARG...]   start PROGRAM under a port connector
%%   stop_port NAME
%%   runs NAME                    how many times the port's program started
%%   entities PAIRING             the EntityIDs registered in the pairing
%%   speed N                      pause the home's clock and set its speed
%%   run_until HH:MM              run the clock until that local time, pause
%%   outcome                      the home's state: LIGHT/EMAIL/PHOTO/PLAYED lines
-mode(compile).

main(Args) ->
    {Pairings, Home} = args(Args, [], none),
    %% EVATAR_LOG_LEVEL=notice shows what port programs write on stderr.
    Level = list_to_existing_atom(os:getenv("EVATAR_LOG_LEVEL", "warning")),
    logger:set_primary_config(level, Level),
    application:load(agent_bridge),
    application:set_env(agent_bridge, listeners, []),
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    [{ok, _} = evatar:create_pairing(Id, Opts) || {Id, Opts} <- Pairings],
    Port = case os:getenv("EVATAR_PORT") of false -> 0; P -> list_to_integer(P) end,
    {ok, _} = agent_bridge:start_listener(test_node, #{ip => {127, 0, 0, 1}, port => Port}),
    {ok, {_, Bound}} = agent_bridge:address(test_node),
    State = start_home(Home, Bound),
    io:format("EVATAR_PORT=~b~n", [Bound]),
    loop(State).

args([], Acc, Home) -> {lists:reverse(Acc), Home};
args(["--home", Spec | Rest], Acc, _) ->
    [Pairing, Cred | SpoolParts] = string:split(Spec, ":", all),
    args(Rest, Acc, {list_to_binary(Pairing), list_to_binary(Cred), lists:join(":", SpoolParts)});
args([Spec | Rest], Acc, Home) ->
    Opts = case string:split(Spec, ":", all) of
               [Id, A, V] when Id =/= "", A =/= "", V =/= "" ->
                   {Id, #{agent_credential => list_to_binary(A),
                          avatar_credential => list_to_binary(V)}};
               [Id, A, V, T] when Id =/= "", A =/= "", V =/= "" ->
                   {Id, #{agent_credential => list_to_binary(A),
                          avatar_credential => list_to_binary(V),
                          feedback_timeout => list_to_integer(T)}};
               _ ->
                   io:format(standard_error, "bad pairing ~s~n", [Spec]),
                   halt(2)
           end,
    {Id1, O} = Opts,
    args(Rest, [{list_to_binary(Id1), O} | Acc], Home).

start_home(none, _Port) ->
    #{};
start_home({Pairing, Cred, Spool}, Port) ->
    {ok, _} = application:ensure_all_started(avatar_sim),
    {ok, Clock} = avatar_sim:start_clock(#{speed => 2, tick => 500,
                                           start => reference_agents_holiday:start_datetime()}),
    {ok, Home} = avatar_sim:start_home(#{clock => Clock, seed => 1,
                                         endpoints => [{{127, 0, 0, 1}, Port}],
                                         spool => Spool,
                                         script => reference_agents_holiday:default_script(),
                                         gateways => [#{pairing => Pairing,
                                                        credential => Cred}]}),
    #{clock => Clock, home => Home}.

loop(S) ->
    case io:get_line('') of
        eof -> halt(0);
        {error, _} -> halt(0);
        Line ->
            Words = string:lexemes(string:trim(Line), " "),
            try command(Words, S) of
                S1 -> loop(S1)
            catch C:R ->
                    io:format("ERROR ~0p~n", [{C, R}]),
                    loop(S)
            end
    end.

command(["port", Name, Program | Args], S) ->
    {ok, _} = agent_bridge:start_port(list_to_binary(Name),
                                      #{command => Program, args => Args,
                                        backoff_min => 100, backoff_max => 2000}),
    ok(S);
command(["stop_port", Name], S) ->
    ok = agent_bridge:stop_port(list_to_binary(Name)),
    ok(S);
command(["runs", Name], S) ->
    [Pid] = [P || {{agent_bridge_port, N}, P, _, _} <- supervisor:which_children(agent_bridge_port_sup),
                  N =:= list_to_binary(Name)],
    io:format("RUNS ~b~n", [agent_bridge_port:runs(Pid)]),
    ok(S);
command(["entities", Pairing], S) ->
    {ok, Registry} = evatar:registry(list_to_binary(Pairing)),
    io:format("ENTITIES ~s~n", [lists:join(" ", [Id || #{entity := Id} <- Registry])]),
    ok(S);
command(["speed", N], #{clock := Clock} = S) ->
    ok = avatar_sim:pause(Clock),
    ok = avatar_sim:set_speed(Clock, list_to_integer(N)),
    ok(S);
command(["run_until", HHMM], #{clock := Clock} = S) ->
    Target = target_ms(avatar_sim:now(Clock), HHMM),
    ok = avatar_sim:resume(Clock),
    wait_clock(Clock, Target),
    ok = avatar_sim:pause(Clock),
    ok(S);
command(["outcome"], #{home := Home} = S) ->
    #{light_log := Log, emails := Emails, photos := Photos, played := Played} =
        avatar_sim:state(Home),
    [io:format("LIGHT ~s ~s ~s~n", [hhmm(T), R, St]) || #{time := T, room := R, state := St} <- Log],
    [io:format("EMAIL ~s\t~s\t~s~n", [F, Sub, lists:join(",", A)])
     || #{file := F, subject := Sub, attachments := A} <- Emails],
    [io:format("PHOTO ~s\t~s\t~s~n", [I, R, F]) || #{id := I, room := R, file := F} <- Photos],
    [io:format("PLAYED ~s\t~b\t~s~n", [K, V, W])
     || #{kind := K, volume := V, what := W} <- Played],
    ok(S);
command(Other, S) ->
    io:format("ERROR unknown command ~0p~n", [Other]),
    S.

ok(S) -> io:format("OK~n"), S.

wait_clock(Clock, Target) ->
    case avatar_sim:now(Clock) >= Target of
        true -> ok;
        false -> timer:sleep(20), wait_clock(Clock, Target)
    end.

hhmm(Ms) ->
    {_, {H, M, _}} = calendar:system_time_to_universal_time(Ms, millisecond),
    io_lib:format("~2..0b:~2..0b", [H, M]).

target_ms(NowMs, HHMM) ->
    [H, M] = [list_to_integer(X) || X <- string:split(HHMM, ":")],
    {Date, _} = calendar:system_time_to_universal_time(NowMs, millisecond),
    Day = (calendar:datetime_to_gregorian_seconds({Date, {0, 0, 0}})
           - calendar:datetime_to_gregorian_seconds({{1970, 1, 1}, {0, 0, 0}})) * 1000,
    T = Day + (H * 60 + M) * 60000,
    case T > NowMs of
        true -> T;
        false -> T + 86400000
    end.
