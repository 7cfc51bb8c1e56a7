%% @doc PropEr properties of the VAs' pure logic: the rules parser (what is
%% written is what is read; any text gives a result or an error naming a
%% line of it), activity recognition (Fig. 10's window), anchoring and the
%% lexicon (the same reports in any order give the same lexicon).
-module(reference_agents_logic_SUITE).

%% The PropEr runner the suites share (apps/evatar_test_kit).
-import(evatar_test_proper, [check/2]).

-include_lib("common_test/include/ct.hrl").
-include_lib("proper/include/proper.hrl").

-export([all/0, suite/0]).
-export([rules_read_back/1, rules_parser_is_total/1, complex_window/1,
         anchors_one_per_object/1, lexicon_order_independent/1]).

suite() -> [{timetrap, {seconds, 90}}].

all() ->
    [rules_read_back, rules_parser_is_total, complex_window, anchors_one_per_object,
     lexicon_order_independent].

%% ---------------------------------------------------------------------------
%% Rules: render random statements as text, parse them back
%% ---------------------------------------------------------------------------

%% @doc Random rules files, written out line by line in the documented
%% syntax (with random comments and blank lines), parse to exactly the
%% statements they were written from, with their line numbers.
rules_read_back(_Config) ->
    check(?FORALL(Spec, rules_spec(), read_back(Spec)), 300).

name() ->
    ?LET({H, T}, {elements("abcdefghijklmnopqrstuvwxyzABC"),
                  list(elements("abcdefghijklmnopqrstuvwxyz0123456789_-"))},
         list_to_binary([H | lists:sublist(T, 12)])).

text() ->
    ?LET(Cs, non_empty(list(elements("abc xyz\"\\#,=.!é"))), unicode:characters_to_binary(Cs)).

value() -> oneof([name(), text()]).

minute() -> integer(0, 1439).

action() ->
    oneof([{light, name(), elements([on, off])},
           {photos, integer(1, 20)},
           {email, text(), elements([with_photos, no_photos])},
           {sms, text()},
           {say, text()},
           alarm]).

condition() -> oneof([dark, {between, minute(), minute()}]).

%% A spec is a list of statements; names are made unique afterwards, and
%% complex parts refer to activities defined earlier.
statement() ->
    frequency([{3, {simple, name(), name(), list({name(), value()})}},
               {2, {complex, name(), integer(1, 3), integer(1, 999), elements([s, min, h])}},
               {3, {policy, name(), oneof([{on, integer(0, 5), oneof([any, name()])},
                                          {at, minute()}]),
                    list(condition()), non_empty(list(action()))}},
               {1, blank}, {1, comment}]).

rules_spec() -> ?LET(S, non_empty(list(statement())), S).

read_back(Spec) ->
    {Lines, Expected} = render(Spec),
    Text = iolist_to_binary([[L, "\n"] || L <- Lines]),
    case reference_agents_rules:parse(Text) of
        {ok, R} ->
            Got = #{simple => reference_agents_rules:simple(R),
                    complex => reference_agents_rules:complex(R),
                    rules => lists:append([reference_agents_rules:policy_rules(P, R)
                                           || P <- reference_agents_rules:policies(R)])},
            Want = Expected#{rules := sort_by_policy(maps:get(rules, Expected))},
            ?WHENFAIL(io:format("~s~n~p~n~p~n", [Text, Want, Got]), Want =:= Got);
        {error, E} ->
            ?WHENFAIL(io:format("~s~n~p~n", [Text, E]), false)
    end.

sort_by_policy(Rules) ->
    Order = lists:foldl(fun(#{policy := P}, Acc) ->
                                case lists:member(P, Acc) of true -> Acc; false -> Acc ++ [P] end
                        end, [], Rules),
    lists:append([[R || #{policy := P1} = R <- Rules, P1 =:= P] || P <- Order]).

render(Spec) ->
    {Lines, _, Exp, _} =
        lists:foldl(fun(S, {Ls, N, Exp, Defined}) ->
                            case line(S, N, Defined) of
                                skip -> {Ls, N, Exp, Defined};
                                {Text, Kind, Term, Defined1} ->
                                    {[Text | Ls], N + 1,
                                     maps:update_with(Kind, fun(L) -> L ++ [Term] end, Exp),
                                     Defined1};
                                {Text, none} ->
                                    {[Text | Ls], N + 1, Exp, Defined}
                            end
                    end, {[], 1, #{simple => [], complex => [], rules => []}, []}, Spec),
    {lists:reverse(Lines), Exp}.

unique(Base, Defined) ->
    Name = <<Base/binary, "x", (integer_to_binary(length(Defined)))/binary>>,
    Name.

line(blank, _N, _D) -> {"   ", none};
line(comment, _N, _D) -> {"# a comment, with \"quotes\" and = signs", none};
line({simple, Base, Service, Params0}, N, D) ->
    Name = unique(Base, D),
    Params = dedupe(Params0),
    Text = ["simple ", Name, " when ", Service,
            [[" ", P, "=", quote(V)] || {P, V} <- Params]],
    {Text, simple, #{name => Name, service => Service, params => Params, line => N}, D ++ [Name]};
line({complex, Base, Parts0, Amount, Unit}, N, D) when length(D) >= 2 ->
    Name = unique(Base, D),
    Parts = lists:usort([lists:nth(1 + (I * 7 + length(D)) rem length(D), D)
                         || I <- lists:seq(0, Parts0)]),
    case Parts of
        [_, _ | _] ->
            %% Windows are at most 7 days.
            Amount1 = case Unit of h -> 1 + Amount rem 168; _ -> Amount end,
            Ms = Amount1 * case Unit of s -> 1000; min -> 60000; h -> 3600000 end,
            Text = ["complex ", Name, " when ", lists:join(" and ", Parts), " within ",
                    integer_to_list(Amount1), " ", atom_to_list(Unit)],
            {Text, complex, #{name => Name, parts => Parts, unless => [], window => Ms, line => N},
             D ++ [Name]};
        _ -> skip
    end;
line({complex, _, _, _, _}, _N, _D) -> skip;
line({policy, _P, {on, _, _}, _C, _A}, _N, []) -> skip;
line({policy, P, Trigger0, Conds, Actions}, N, D) ->
    {TText, Trigger} = case Trigger0 of
                           {on, I, any} ->
                               A = lists:nth(1 + I rem length(D), D),
                               {["on ", A], {activity, A, any}};
                           {on, I, Room} ->
                               A = lists:nth(1 + I rem length(D), D),
                               {["on ", A, " in ", Room], {activity, A, Room}};
                           {at, M} ->
                               {["at ", reference_agents_policy:format_minute(M)], {at, M}}
                       end,
    CText = case Conds of
                [] -> [];
                _ -> [" if ", lists:join(" and ", [cond_text(C) || C <- Conds])]
            end,
    Text = ["policy ", P, " ", TText, CText, " do ",
            lists:join(", ", [reference_agents_rules:format_action(A) || A <- Actions])],
    {Text, rules, #{policy => P, trigger => Trigger, conditions => Conds, actions => Actions,
                    line => N}, D}.

cond_text(dark) -> "dark";
cond_text({between, A, B}) ->
    ["between ", reference_agents_policy:format_minute(A), " and ",
     reference_agents_policy:format_minute(B)].

dedupe(Params) ->
    lists:reverse(lists:foldl(fun({P, V}, Acc) ->
                                      case lists:keymember(P, 1, Acc) of
                                          true -> Acc;
                                          false -> [{P, V} | Acc]
                                      end
                              end, [], Params)).

quote(V) ->
    [$", string:replace(string:replace(V, "\\", "\\\\", all), "\"", "\\\"", all), $"].

%% @doc Any text made of the language's words, punctuation and junk is
%% either accepted or refused with an error naming one of its lines.
rules_parser_is_total(_Config) ->
    Word = elements(["simple", "complex", "policy", "when", "and", "within", "unless", "on", "at",
                     "in", "if", "dark", "between", "do", "light", "photos", "email", "with",
                     "sms", "say", "alarm", "on", "off", "m", "X", "2", "min", "18:00", "99:99",
                     ",", "=", "\"", "\"quoted\"", "#", "é", "\t", "\\", "-1", "all"]),
    Line = ?LET(Ws, list(Word), lists:join(" ", Ws)),
    check(?FORALL(Lines, list(Line),
                  begin
                      Text = unicode:characters_to_binary(lists:join("\n", Lines)),
                      case reference_agents_rules:parse(Text) of
                          {ok, _} -> true;
                          {error, #{line := L, message := M}} ->
                              is_binary(M) andalso L >= 1 andalso L =< max(1, length(Lines))
                      end
                  end), 500).

%% ---------------------------------------------------------------------------
%% Activities
%% ---------------------------------------------------------------------------

%% @doc Motion and a wrong password make an intruder exactly when they are
%% at most the window apart, in either order (Fig. 10).
complex_window(_Config) ->
    {ok, Rules} = reference_agents_rules:parse(
                    <<"simple motion when MotionDetected Motion=yes\n"
                      "simple failed when PasswordInput WrongPassword=yes\n"
                      "complex intruder when motion and failed within 2 min\n">>),
    P = fun(motion, T) -> #{service => <<"MotionDetected">>, params => [{<<"Motion">>, <<"yes">>}],
                            time => T};
           (failed, T) -> #{service => <<"PasswordInput">>,
                            params => [{<<"WrongPassword">>, <<"yes">>}], time => T}
        end,
    check(?FORALL({T1, T2}, {integer(0, 600000), integer(0, 600000)},
                  begin
                      [{A, TA}, {B, TB}] = lists:sort(fun({_, X}, {_, Y}) -> X =< Y end,
                                                      [{motion, T1}, {failed, T2}]),
                      S0 = reference_agents_activity:new(Rules),
                      {S1, _} = reference_agents_activity:perceive(P(A, TA), S0),
                      {_, Found} = reference_agents_activity:perceive(P(B, TB), S1),
                      Intruder = lists:member(<<"intruder">>, [N || #{activity := N} <- Found]),
                      Intruder =:= (TB - TA =< 120000)
                  end), 500).

%% ---------------------------------------------------------------------------
%% Anchoring and the lexicon
%% ---------------------------------------------------------------------------

colours() -> [<<"red">>, <<"green">>, <<"blue">>, <<"yellow">>].

%% @doc Objects of different colours, each seen many times with an error of
%% up to 80 mm on each axis (two sightings are never more than the 250 mm
%% apart that still count as one place), give one anchor each, whose symbol
%% never changes.
anchors_one_per_object(_Config) ->
    Sighting = ?LET({C, DX, DY}, {elements(colours()), integer(-80, 80), integer(-80, 80)},
                    {C, DX, DY}),
    check(?FORALL(Seen, non_empty(list(Sighting)),
                  begin
                      Home = maps:from_list(lists:zip(colours(), [{200, 200}, {900, 700},
                                                                  {1600, 300}, {1000, 1300}])),
                      {As, Outcomes} =
                          lists:foldl(fun({{C, DX, DY}, T}, {A, Acc}) ->
                                              {X, Y} = maps:get(C, Home),
                                              {A1, O} = reference_agents_anchor:perceive(
                                                          #{colour => C, position => {X + DX, Y + DY},
                                                            time => T}, A),
                                              {A1, [{C, O} | Acc]}
                                      end, {reference_agents_anchor:new(<<"r">>), []},
                                      lists:zip(Seen, lists:seq(1, length(Seen)))),
                      Colours = lists:usort([C || {C, _, _} <- Seen]),
                      Symbols = lists:usort([{C, S} || {C, {_, S}} <- Outcomes]),
                      length(reference_agents_anchor:anchors(As)) =:= length(Colours)
                          andalso length(Symbols) =:= length(Colours)
                  end), 300).

report() ->
    ?LET({Agent, Anchors}, {elements([<<"va1">>, <<"va2">>, <<"va3">>]),
                            list({elements(colours()), integer(0, 2000), integer(0, 1500)})},
         {Agent, [#{symbol => <<Agent/binary, "-", (integer_to_binary(I))/binary>>,
                    colour => C, position => {X, Y}}
                  || {I, {C, X, Y}} <- lists:zip(lists:seq(1, length(Anchors)), Anchors)]}).

%% @doc The lexicon does not depend on the order of the reports, and every
%% anchor reported is named in exactly one entry, once.
lexicon_order_independent(_Config) ->
    Reports = ?LET(Rs, list(report()),
                   maps:to_list(maps:from_list(Rs))),
    check(?FORALL({Rs, Seed}, {Reports, integer()},
                  begin
                      L = reference_agents_lexicon:build(Rs),
                      Shuffled = shuffle(Rs, Seed),
                      Named = lists:sort([{A, S} || #{names := Ns} <- L, {A, S} <- maps:to_list(Ns)]),
                      Reported = lists:sort([{A, S} || {A, As} <- Rs, #{symbol := S} <- As]),
                      L =:= reference_agents_lexicon:build(Shuffled)
                          andalso Named =:= Reported
                  end), 300).

shuffle(List, Seed) ->
    S = rand:seed_s(exsss, Seed),
    {Keyed, _} = lists:foldl(fun(X, {Acc, St}) ->
                                     {K, St1} = rand:uniform_s(St),
                                     {[{K, X} | Acc], St1}
                             end, {[], S}, List),
    [X || {_, X} <- lists:sort(Keyed)].
