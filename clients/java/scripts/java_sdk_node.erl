%% @doc One EVATAR node for the Java SDK's tests, driven line by line on
%% stdin (scripts/test-node.sh does the plain node; this adds the simulated
%% home and port connectors). Answers on stdout, one line each, `OK ...' or
%% `ERROR ...'; `state' answers several lines and then `END'. EOF on stdin
%% halts the node.
%%
%%   home PAIRING AVATAR_CREDENTIAL SPOOL  avatar_sim's easy smart home (the
%%                                         holiday evening's script) joins
%%   run HH:MM                             simulated time runs to HH:MM, paused after
%%   state                                 lights, e-mails, photos, sounds of the home
%%   port NAME COMMAND ARG...              agent_bridge:start_port/2 (fields split by TAB)
%%   stop_port NAME
%%   entities PAIRING                      the entity ids registered in the pairing
-module(java_sdk_node).
-export([main/1]).

main(Specs) ->
    {ok, _} = application:ensure_all_started(evatar),
    {ok, _} = application:ensure_all_started(agent_bridge),
    {ok, _} = application:ensure_all_started(avatar_sim),
    [{ok, _} = evatar:create_pairing(list_to_binary(Id),
                                     #{agent_credential => list_to_binary(A),
                                       avatar_credential => list_to_binary(V)})
     || Spec <- Specs, [Id, A, V] <- [string:split(Spec, ":", all)]],
    {ok, _} = agent_bridge:start_listener(java_sdk_node, #{ip => {127, 0, 0, 1}, port => 0}),
    {ok, {_, Port}} = agent_bridge:address(java_sdk_node),
    io:format("EVATAR_PORT=~b~n", [Port]),
    loop(#{port => Port}).

loop(S) ->
    case io:get_line('') of
        eof -> halt(0);
        {error, _} -> halt(0);
        Line ->
            S1 = try command(string:split(string:trim(Line, trailing, "\r\n"), "\t", all), S)
                 catch C:E:St ->
                         io:format("ERROR ~0p~n", [{C, E, hd(St)}]),
                         S
                 end,
            loop(S1)
    end.

command(["home", Pairing, Cred, Spool], #{port := Port} = S) ->
    {ok, Clock} = avatar_sim:start_clock(#{speed => 2, tick => 500,
                                           start => reference_agents_holiday:start_datetime()}),
    {ok, Home} = avatar_sim:start_home(#{clock => Clock, seed => 1,
                                         endpoints => [{{127, 0, 0, 1}, Port}],
                                         spool => Spool,
                                         script => reference_agents_holiday:default_script(),
                                         gateways => [#{pairing => list_to_binary(Pairing),
                                                        credential => list_to_binary(Cred)}]}),
    io:format("OK~n"),
    S#{clock => Clock, home => Home};
command(["run", HHMM], #{clock := Clock} = S) ->
    [H, M] = [list_to_integer(X) || X <- string:split(HHMM, ":")],
    ok = avatar_sim:pause(Clock),
    ok = avatar_sim:set_speed(Clock, 1000),
    Now = avatar_sim:now(Clock),
    Day = Now - Now rem 86400000,
    T0 = Day + (H * 60 + M) * 60000,
    Target = case T0 > Now of true -> T0; false -> T0 + 86400000 end,
    ok = avatar_sim:resume(Clock),
    wait_clock(Clock, Target),
    ok = avatar_sim:pause(Clock),
    io:format("OK ~s~n", [hhmm(avatar_sim:now(Clock))]),
    S;
command(["state"], #{home := Home} = S) ->
    #{light_log := Log, emails := Emails, photos := Photos, played := Played} = avatar_sim:state(Home),
    [io:format("light ~s ~s ~s~n", [hhmm(T), R, St]) || #{time := T, room := R, state := St} <- Log],
    [io:format("email ~s ~s ~s ~s~n", [hhmm(T), Subj, F, lists:join(",", As)])
     || #{time := T, subject := Subj, file := F, attachments := As} <- Emails],
    [io:format("photo ~s ~s ~s~n", [Id, R, F]) || #{id := Id, room := R, file := F} <- Photos],
    [io:format("played ~s ~b ~s~n", [K, V, W]) || #{kind := K, volume := V, what := W} <- Played],
    io:format("END~n"),
    S;
command(["port", Name, Command | Args], S) ->
    {ok, _} = agent_bridge:start_port(list_to_binary(Name), #{command => Command, args => Args}),
    io:format("OK~n"),
    S;
command(["stop_port", Name], S) ->
    ok = agent_bridge:stop_port(list_to_binary(Name)),
    io:format("OK~n"),
    S;
command(["entities", Pairing], S) ->
    Ids = [Id || #{entity := Id} <- entities(list_to_binary(Pairing))],
    io:format("OK ~s~n", [lists:join(" ", Ids)]),
    S;
command(Other, S) ->
    io:format("ERROR unknown command ~0p~n", [Other]),
    S.

entities(Pairing) ->
    case evatar:registry(Pairing) of
        {ok, Es} -> Es;
        _ -> []
    end.

wait_clock(Clock, Target) ->
    case avatar_sim:now(Clock) >= Target of
        true -> ok;
        false -> timer:sleep(20), wait_clock(Clock, Target)
    end.

hhmm(Ms) ->
    {_, {H, M, _}} = calendar:system_time_to_universal_time(Ms, millisecond),
    io_lib:format("~2..0b:~2..0b", [H, M]).
