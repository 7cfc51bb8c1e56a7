%% @doc Internal. Activity recognition, pure: percepts (sensor readings
%% from the VA's sensor emulators) become simple activities by the rules
%% file's `simple' lines, and simple activities seen together within a time
%% window become complex ones (`complex' lines; the paper's Fig. 10: motion
%% and a failed authorisation make an intruder). Time is an argument: the
%% simulated clock's milliseconds in the scenarios.
-module(reference_agents_activity).

-export([new/1, perceive/2, history/1, keyword/1]).

-export_type([state/0, percept/0, instance/0]).

-type percept() :: #{service := binary(),
                     params := [{binary(), binary()}],
                     time := integer()}.
%% A recognised activity. `room' comes from the reading's Room parameter
%% (`any' without one); `parts' are the instances a complex one was made of.
-type instance() :: #{activity := binary(),
                      kind := simple | complex,
                      time := integer(),
                      room := binary() | any,
                      parts := [instance()]}.

-record(st, {simple :: [reference_agents_rules:simple()],
             complex :: [reference_agents_rules:complex()],
             horizon :: pos_integer(),
             history = [] :: [instance()],          % newest first
             fired = #{} :: #{binary() => integer()}}).
-opaque state() :: #st{}.

-define(MIN_HORIZON, 60000).

%% @doc A recogniser for the activities of a rules file.
-spec new(reference_agents_rules:rules()) -> state().
new(Rules) ->
    Complex = reference_agents_rules:complex(Rules),
    Horizon = lists:max([?MIN_HORIZON | [W || #{window := W} <- Complex]]),
    #st{simple = reference_agents_rules:simple(Rules), complex = Complex,
        horizon = Horizon}.

%% @doc Takes one reading; returns the activities it completes: the simple
%% ones it matches, then every complex one that now holds, in file order. A
%% complex activity is reported once per window: the intruder who keeps
%% moving raises the alarm once, not at every step.
-spec perceive(percept(), state()) -> {state(), [instance()]}.
perceive(#{service := Service, params := Params, time := Now}, #st{} = S0) ->
    Room = room(Params),
    Simple = [#{activity => Name, kind => simple, time => Now, room => Room, parts => []}
              || #{name := Name, service := Svc, params := Want} <- S0#st.simple,
                 keyword(Svc) =:= keyword(Service), matches(Want, Params)],
    S1 = S0#st{history = lists:reverse(Simple) ++ prune(Now, S0)},
    {S2, Complex} = complex(S0#st.complex, [A || #{activity := A} <- Simple], Now, S1, []),
    {S2, Simple ++ Complex}.

%% @doc The activities still within the longest window, newest first.
-spec history(state()) -> [instance()].
history(#st{history = H}) -> H.

%% @doc The keyword form BIL compares with: lower case, letters and digits.
-spec keyword(binary()) -> binary().
keyword(B) ->
    << <<C>> || <<C>> <= string:lowercase(B), (C >= $a andalso C =< $z) orelse
                                                (C >= $0 andalso C =< $9) >>.

matches(Want, Params) ->
    Have = [{keyword(N), keyword(V)} || {N, V} <- Params],
    lists:all(fun({N, V}) -> lists:member({keyword(N), keyword(V)}, Have) end, Want).

room(Params) ->
    case [V || {N, V} <- Params, keyword(N) =:= <<"room">>] of
        [Room | _] -> Room;
        [] -> any
    end.

prune(Now, #st{history = H, horizon = Horizon}) ->
    [I || #{time := T} = I <- H, T >= Now - Horizon].

%% New is the names recognised at this instant, so a complex activity is
%% only looked at when one of its parts has just happened; those found are
%% added to New in turn, so a complex one can be part of a later one.
complex([], _New, _Now, S, Acc) ->
    {S, lists:reverse(Acc)};
complex([#{name := Name, parts := Parts, unless := Unless, window := W} | Rest],
        New, Now, S, Acc) ->
    Recent = [I || #{time := T} = I <- S#st.history, T >= Now - W],
    Fresh = lists:any(fun(P) -> lists:member(P, New) end, Parts),
    Quiet = case S#st.fired of
                #{Name := Last} -> Last < Now - W;
                _ -> true
            end,
    Found = [latest(P, Recent) || P <- Parts],
    Vetoed = lists:any(fun(U) -> latest(U, Recent) =/= none end, Unless),
    case Fresh andalso Quiet andalso not lists:member(none, Found) andalso not Vetoed of
        true ->
            I = #{activity => Name, kind => complex, time => Now,
                  room => common_room(Found), parts => Found},
            S1 = S#st{history = [I | S#st.history], fired = (S#st.fired)#{Name => Now}},
            complex(Rest, [Name | New], Now, S1, [I | Acc]);
        false ->
            complex(Rest, New, Now, S, Acc)
    end.

latest(Name, Recent) ->
    case [I || #{activity := A} = I <- Recent, A =:= Name] of
        [I | _] -> I;
        [] -> none
    end.

common_room(Parts) ->
    case lists:usort([R || #{room := R} <- Parts, R =/= any]) of
        [Room | _] -> Room;
        [] -> any
    end.
